"""Radiotap header parsing: every present word, namespaces, alignment, per-chain signal.

Two ways in:

* :func:`parse` walks one header field by field and returns a
  :class:`RadiotapInfo` (the API edge, and the fallback for unusual headers).
* :func:`compile_layout` walks one header once and returns a
  :class:`Layout`: the byte offsets of the fields DF needs. Every header with
  the same sequence of present words has the same offsets (fields are
  fixed-size and aligned relative to the header start), so a batch decoder can
  read them for thousands of frames at once with numpy gathers.

Rules (radiotap.org and the radiotap-library reference iterator):

* All values are little-endian; fields are naturally aligned relative to the
  start of the header, in bit order within a namespace.
* Bit 31 of a present word means another word follows; bits 29–31 of every
  word are reserved for namespace switches and never data fields.
* Bit 29 (radiotap namespace) restarts the bit index at 0 in a new radiotap
  namespace; bit 30 (vendor namespace) carries ``OUI[3], sub_namespace,
  skip_length`` (align 2) and the vendor data (``skip_length`` bytes) is
  skipped as a whole. Without either bit the index continues at 32, 64, …
* The first unknown radiotap-namespace bit stops the walk (its size is
  unknown); ``it_len`` still locates the 802.11 frame.
* Namespace 0's dBm antenna signal (bit 5) is the combined signal; every later
  radiotap namespace holding bit 5 and bit 11 (antenna) is one receive chain,
  as Linux mac80211 writes them.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from rfsas_hw.errors import CaptureFormatError

FLAG_FCS_AT_END = 0x10
"""Radiotap Flags bit: the 802.11 frame ends with a 4-byte FCS."""
FLAG_BAD_FCS = 0x40
"""Radiotap Flags bit: the receiver found the FCS wrong."""

BIT_TSFT = 0
BIT_FLAGS = 1
BIT_RATE = 2
BIT_CHANNEL = 3
BIT_DBM_ANTSIGNAL = 5
BIT_DBM_ANTNOISE = 6
BIT_ANTENNA = 11
BIT_RX_FLAGS = 14
BIT_TLV = 28
BIT_RADIOTAP_NS = 29
BIT_VENDOR_NS = 30
BIT_EXT = 31

NS_SWITCH_MASK = (1 << BIT_RADIOTAP_NS) | (1 << BIT_VENDOR_NS)
DATA_BITS_MASK = (1 << BIT_RADIOTAP_NS) - 1
"""Bits 0–28 of a present word: the ones that can name data fields."""

MIN_HEADER_LEN = 8

# bit -> (name, alignment in bytes, size in bytes). Bits 0–27 of the radiotap
# namespace; 28 (TLV) ends the fixed fields and is handled by the walker.
FIELDS: dict[int, tuple[str, int, int]] = {
    0: ("TSFT", 8, 8),
    1: ("Flags", 1, 1),
    2: ("Rate", 1, 1),
    3: ("Channel", 2, 4),
    4: ("FHSS", 2, 2),
    5: ("dBm antenna signal", 1, 1),
    6: ("dBm antenna noise", 1, 1),
    7: ("Lock quality", 2, 2),
    8: ("TX attenuation", 2, 2),
    9: ("dB TX attenuation", 2, 2),
    10: ("dBm TX power", 1, 1),
    11: ("Antenna", 1, 1),
    12: ("dB antenna signal", 1, 1),
    13: ("dB antenna noise", 1, 1),
    14: ("RX flags", 2, 2),
    15: ("TX flags", 2, 2),
    16: ("RTS retries", 1, 1),
    17: ("data retries", 1, 1),
    18: ("XChannel", 4, 8),
    19: ("MCS", 1, 3),
    20: ("A-MPDU status", 4, 8),
    21: ("VHT", 2, 12),
    22: ("timestamp", 8, 12),
    23: ("HE", 2, 12),
    24: ("HE-MU", 2, 12),
    25: ("HE-MU-other-user", 2, 6),
    26: ("0-length-PSDU", 1, 1),
    27: ("L-SIG", 2, 4),
}
VENDOR_HEADER_ALIGN = 2
VENDOR_HEADER_SIZE = 6

_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_VENDOR = struct.Struct("<3sBH")


@dataclass(frozen=True, slots=True)
class VendorNamespace:
    """One vendor namespace met in a header; its data is skipped, not decoded."""

    oui: int
    """Organisationally unique identifier (24 bits)."""
    sub_namespace: int
    """Vendor-defined sub-namespace number."""
    skip_length: int
    """Bytes of vendor data after the 6-byte namespace field."""


@dataclass(frozen=True, slots=True)
class RadiotapInfo:
    """What one radiotap header says about the frame behind it.

    Absent fields are None; ``chains`` is empty when the header has no
    per-chain namespaces.
    """

    length: int
    """``it_len``: header length in bytes; the 802.11 frame starts here."""
    present: tuple[int, ...]
    """Every present word, in order."""
    tsft_us: int | None
    """TSFT: the receiver's MAC clock when the frame's first bit arrived, µs."""
    flags: int | None
    """Flags byte (``FLAG_FCS_AT_END``, ``FLAG_BAD_FCS``, …)."""
    rate_500kbps: int | None
    """Legacy data rate, 500 kb/s units."""
    channel_mhz: int | None
    """Channel centre frequency, MHz."""
    channel_flags: int | None
    """Channel flags (0x80 2 GHz, 0x100 5 GHz, …)."""
    signal_dbm: int | None
    """Combined signal at the antennas (namespace 0, bit 5), dBm."""
    noise_dbm: int | None
    """Noise at the antennas (namespace 0, bit 6), dBm."""
    antenna: int | None
    """Antenna index in namespace 0 (single-antenna receivers), first antenna 0."""
    rx_flags: int | None
    """RX flags (0x0002: PLCP CRC failed)."""
    chains: tuple[tuple[int, int], ...]
    """Per-chain ``(antenna index, signal dBm)`` pairs, in header order."""
    vendor_namespaces: tuple[VendorNamespace, ...] = ()
    """Vendor namespaces met (their data is skipped)."""
    stopped_at_bit: int | None = None
    """First field the walk could not interpret (unknown bit, or 28 for a TLV list)."""

    @property
    def fcs_at_end(self) -> bool:
        """True when the 802.11 frame ends with a 4-byte FCS."""
        return bool((self.flags or 0) & FLAG_FCS_AT_END)

    @property
    def bad_fcs(self) -> bool:
        """True when the receiver reported a failed FCS check."""
        return bool((self.flags or 0) & FLAG_BAD_FCS)


@dataclass(slots=True)
class Layout:
    """Byte offsets (from the header start) of the fields DF needs, for one present-word sequence.

    An offset of -1 means the field is absent.
    """

    present: tuple[int, ...]
    """The present words this layout was compiled from."""
    min_len: int
    """Smallest ``it_len`` that holds every field walked."""
    tsft: int = -1
    flags: int = -1
    channel: int = -1
    signal: int = -1
    antenna: int = -1
    chains: list[tuple[int, int]] = field(default_factory=list)
    """``(antenna offset, signal offset)`` per chain namespace, in header order."""
    vendor_skip_at: int = -1
    """Offset of the ``skip_length`` of the one vendor namespace, or -1 when none."""
    vendor_skip: int = -1
    """The vendor ``skip_length`` these offsets assume (fields after vendor data move with it)."""
    vectorisable: bool = True
    """False with several vendor namespaces (decode such frames one by one)."""


def _err(msg: str) -> CaptureFormatError:
    return CaptureFormatError(f"radiotap: {msg}")


def read_present_words(buf: bytes | memoryview, start: int, it_len: int) -> tuple[int, ...]:
    """The present words of the header at ``start`` (whose ``it_len`` is given).

    Raises:
        CaptureFormatError: the Ext chain runs past ``it_len``.
    """
    words: list[int] = []
    off = 4
    while True:
        if off + 4 > it_len:
            raise _err(
                f"present word {len(words) + 1} at header offset {off} runs past it_len {it_len}"
            )
        word = _U32.unpack_from(buf, start + off)[0]
        words.append(word)
        off += 4
        if not word & (1 << BIT_EXT):
            return tuple(words)


class _Walk:
    """One pass over a header's data fields, recording where each one sits."""

    __slots__ = ("buf", "it_len", "start", "stopped", "vendor_at", "vendors")

    def __init__(self, buf: bytes | memoryview, start: int, it_len: int) -> None:
        self.buf = buf
        self.start = start
        self.it_len = it_len
        self.vendors: list[VendorNamespace] = []
        self.stopped: int | None = None
        self.vendor_at = -1
        """Header offset of the first vendor namespace field."""

    def run(self, words: tuple[int, ...]) -> tuple[int, dict[int, int], list[tuple[int, int]]]:
        """Walk the data fields.

        Returns (end offset, namespace-0 bit -> offset, per-chain (antenna
        offset, signal offset)).

        Raises:
            CaptureFormatError: a field runs past ``it_len``, or a word sets
                both namespace bits.
        """
        pos = 4 + 4 * len(words)
        it_len = self.it_len
        ns_no = 0
        base = 0
        in_vendor = False
        vendor_skip = 0
        ns0: dict[int, int] = {}
        chains: list[tuple[int, int]] = []
        for wi, word in enumerate(words):
            if wi:
                prev = words[wi - 1]
                if prev & (1 << BIT_RADIOTAP_NS):
                    in_vendor, base = False, 0
                    ns_no += 1
                elif prev & (1 << BIT_VENDOR_NS):
                    in_vendor, base = True, 0
                    ns_no += 1
                    # The vendor data is opaque: jump over all of it on entry.
                    pos += vendor_skip
                    if pos > it_len:
                        raise _err(
                            f"vendor namespace data ({vendor_skip} bytes) runs past it_len {it_len}"
                        )
                else:
                    base += 32
            if word & NS_SWITCH_MASK == NS_SWITCH_MASK:
                raise _err(
                    f"present word {wi + 1} (0x{word:08x}) sets both namespace bits 29 and 30"
                )
            if not in_vendor:
                sig_off = ant_off = -1
                bits = word & DATA_BITS_MASK
                while bits:
                    low = bits & -bits
                    bits ^= low
                    index = base + low.bit_length() - 1
                    spec = FIELDS.get(index)
                    if spec is None:
                        # TLV list (28) or an undefined bit: nothing after it can be located.
                        self.stopped = index
                        return pos, ns0, chains
                    name, align, size = spec
                    pos = (pos + align - 1) & -align
                    if pos + size > it_len:
                        raise _err(f"field {name} at header offset {pos} runs past it_len {it_len}")
                    if ns_no == 0:
                        ns0[index] = pos
                    elif index == BIT_DBM_ANTSIGNAL:
                        sig_off = pos
                    elif index == BIT_ANTENNA:
                        ant_off = pos
                    pos += size
                if ns_no and sig_off >= 0 and ant_off >= 0:
                    chains.append((ant_off, sig_off))
            if word & (1 << BIT_VENDOR_NS):
                pos = (pos + VENDOR_HEADER_ALIGN - 1) & -VENDOR_HEADER_ALIGN
                if pos + VENDOR_HEADER_SIZE > it_len:
                    raise _err(
                        f"vendor namespace field at header offset {pos} runs past it_len {it_len}"
                    )
                if not self.vendors:
                    self.vendor_at = pos
                oui, subns, skip = _VENDOR.unpack_from(self.buf, self.start + pos)
                self.vendors.append(VendorNamespace(int.from_bytes(oui, "big"), subns, skip))
                vendor_skip = skip
                pos += VENDOR_HEADER_SIZE
        if in_vendor:
            return pos, ns0, chains
        # A vendor namespace bit in the last word with no word after it: its
        # data still follows the namespace field.
        if words[-1] & (1 << BIT_VENDOR_NS):
            pos += vendor_skip
            if pos > it_len:
                raise _err(f"vendor namespace data ({vendor_skip} bytes) runs past it_len {it_len}")
        return pos, ns0, chains


def _header(buf: bytes | memoryview, start: int, avail: int) -> int:
    if avail < MIN_HEADER_LEN:
        raise _err(f"frame has {avail} bytes, shorter than the 8-byte radiotap header")
    version = buf[start]
    if version != 0:
        raise _err(f"unsupported radiotap version {version} (expected 0)")
    it_len: int = _U16.unpack_from(buf, start + 2)[0]
    if it_len < MIN_HEADER_LEN:
        raise _err(f"it_len {it_len} is shorter than the 8-byte header")
    if it_len > avail:
        raise _err(f"it_len {it_len} is larger than the captured frame ({avail} bytes)")
    return it_len


def parse_at(buf: bytes | memoryview, start: int = 0, avail: int | None = None) -> RadiotapInfo:
    """Parse the radiotap header at ``buf[start:]``; ``avail`` bytes belong to the frame.

    Raises:
        CaptureFormatError: version is not 0, ``it_len`` is shorter than the
            header or longer than the frame, or a field runs past ``it_len``.
            The message gives the offset inside the header.
    """
    if avail is None:
        avail = len(buf) - start
    it_len = _header(buf, start, avail)
    words = read_present_words(buf, start, it_len)
    walk = _Walk(buf, start, it_len)
    _, ns0, chain_offs = walk.run(words)

    def u8(index: int) -> int | None:
        off = ns0.get(index)
        return None if off is None else buf[start + off]

    def s8(index: int) -> int | None:
        off = ns0.get(index)
        if off is None:
            return None
        v = buf[start + off]
        return v - 256 if v > 127 else v

    tsft_off = ns0.get(BIT_TSFT)
    chan_off = ns0.get(BIT_CHANNEL)
    rx_off = ns0.get(BIT_RX_FLAGS)
    chains = []
    for ant_off, sig_off in chain_offs:
        sig = buf[start + sig_off]
        chains.append((int(buf[start + ant_off]), sig - 256 if sig > 127 else int(sig)))
    return RadiotapInfo(
        length=it_len,
        present=words,
        tsft_us=None if tsft_off is None else _U64.unpack_from(buf, start + tsft_off)[0],
        flags=u8(BIT_FLAGS),
        rate_500kbps=u8(BIT_RATE),
        channel_mhz=None if chan_off is None else _U16.unpack_from(buf, start + chan_off)[0],
        channel_flags=None if chan_off is None else _U16.unpack_from(buf, start + chan_off + 2)[0],
        signal_dbm=s8(BIT_DBM_ANTSIGNAL),
        noise_dbm=s8(BIT_DBM_ANTNOISE),
        antenna=u8(BIT_ANTENNA),
        rx_flags=None if rx_off is None else _U16.unpack_from(buf, start + rx_off)[0],
        chains=tuple(chains),
        vendor_namespaces=tuple(walk.vendors),
        stopped_at_bit=walk.stopped,
    )


def parse(buf: bytes) -> RadiotapInfo:
    """Parse the radiotap header at the start of ``buf`` (header plus, usually, the 802.11 frame).

    Raises:
        CaptureFormatError: malformed header; the message names the header offset.
    """
    return parse_at(buf, 0, len(buf))


def compile_layout(buf: bytes | memoryview, start: int, avail: int) -> Layout:
    """Field offsets for every header with the same present words as the one at ``start``.

    Raises:
        CaptureFormatError: the header itself is malformed.
    """
    it_len = _header(buf, start, avail)
    words = read_present_words(buf, start, it_len)
    walk = _Walk(buf, start, it_len)
    end, ns0, chains = walk.run(words)
    layout = Layout(present=words, min_len=end, chains=chains)
    layout.tsft = ns0.get(BIT_TSFT, -1)
    layout.flags = ns0.get(BIT_FLAGS, -1)
    layout.channel = ns0.get(BIT_CHANNEL, -1)
    layout.signal = ns0.get(BIT_DBM_ANTSIGNAL, -1)
    layout.antenna = ns0.get(BIT_ANTENNA, -1)
    if len(walk.vendors) > 1:
        # The second vendor header's place depends on the first one's skip length.
        layout.vectorisable = False
    elif walk.vendors:
        # The one vendor header precedes all vendor data, so its place is fixed;
        # what follows the vendor data is valid for this skip length only.
        layout.vendor_skip_at = walk.vendor_at + 4
        layout.vendor_skip = walk.vendors[0].skip_length
    return layout
