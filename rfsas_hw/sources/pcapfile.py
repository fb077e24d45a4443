"""pcap and pcapng containers: where each frame is, when it was captured, which link type.

:class:`CaptureParser` is a push parser: feed it bytes as they arrive (a file
read in large blocks, or a pipe), ask for chunks of complete frames. One
Python-level step per record or block finds the offsets (a large pcap
buffer is walked with numpy, :func:`find_pcap_records`); everything else
(timestamps, lengths, interface ids) is read with numpy for the whole chunk.

* pcap: both byte orders, microsecond and nanosecond magic.
* pcapng: both byte orders (per section), several sections, several
  interfaces each with its own link type and timestamp resolution
  (``if_tsresol``, decimal or binary) and offset (``if_tsoffset``); enhanced
  and obsolete packet blocks; other standard blocks are skipped.

Damage costs as little as possible: a zero-length or truncated frame is one
:class:`FrameProblem`; a corrupt record header or block is reported and the
parser searches forward for the next plausible record. Only a file whose
first bytes are not a capture at all is fatal.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import CaptureFormatError

PCAP_MAGIC_US = 0xA1B2C3D4
PCAP_MAGIC_NS = 0xA1B23C4D
PCAPNG_SHB = 0x0A0D0D0A
PCAPNG_BYTE_ORDER_MAGIC = 0x1A2B3C4D

BT_IDB = 0x00000001
BT_PB = 0x00000002
BT_SPB = 0x00000003
BT_NRB = 0x00000004
BT_ISB = 0x00000005
BT_EPB = 0x00000006
BT_JOURNAL = 0x00000009
BT_DSB = 0x0000000A
BT_CUSTOM = 0x00000BAD
BT_CUSTOM_NOCOPY = 0x40000BAD
_SKIPPED_BLOCKS = frozenset({BT_NRB, BT_ISB, BT_JOURNAL, BT_DSB, BT_CUSTOM, BT_CUSTOM_NOCOPY})
_KNOWN_BLOCKS = _SKIPPED_BLOCKS | {PCAPNG_SHB, BT_IDB, BT_PB, BT_SPB, BT_EPB}

OPT_END = 0
OPT_IF_TSRESOL = 9
OPT_IF_TSOFFSET = 14

MAX_CAPLEN = 262_144
"""Largest plausible captured frame, bytes (Wireshark's limit for ordinary link types)."""
MAX_BLOCK = 16 * 1024 * 1024
"""Largest plausible pcapng block, bytes."""
RESYNC_LIMIT = 4 * 1024 * 1024
"""How far past a corrupt record the parser searches for the next one, bytes."""
NS_PER_S = 1_000_000_000

# Problem reasons (the keys of SourceStats.skipped).
R_EMPTY = "zero-length frame"
R_TRUNCATED = "truncated record"
R_CORRUPT = "corrupt record header"
R_UNKNOWN_BLOCK = "unknown pcapng block"
R_BAD_BLOCK = "malformed pcapng block"
R_NO_TIMESTAMP = "pcapng simple packet (no timestamp)"
R_INTERFACE = "undefined pcapng interface"


@dataclass(frozen=True, slots=True)
class FrameProblem:
    """One frame or record that could not be used, and where it was."""

    reason: str
    """Short reason, used as the skip-counter key."""
    frame_no: int
    """Frame number (1-based), or 0 for a non-frame record (a pcapng block)."""
    byte_offset: int
    """Byte offset of the record in the file or stream."""
    detail: str
    """What was wrong."""

    def error(self, name: str) -> CaptureFormatError:
        """The error to report, naming the capture, frame and offset."""
        where = f"frame {self.frame_no} at byte {self.byte_offset}"
        if not self.frame_no:
            where = f"byte {self.byte_offset}"
        return CaptureFormatError(f"{name}: {where}: {self.detail}")


@dataclass(slots=True)
class Interface:
    """A pcapng interface (or the single link of a pcap file)."""

    linktype: int
    """Link-layer header type (127 radiotap, 105 bare 802.11, …)."""
    tsresol: int = 6
    """``if_tsresol``: low 7 bits the exponent; top bit set means base 2, else base 10."""
    tsoffset_s: int = 0
    """``if_tsoffset``: seconds added to every timestamp."""


@dataclass(slots=True)
class Chunk:
    """Complete frames found in one buffer, in capture order."""

    buf: bytes
    """The buffer the offsets refer to."""
    start: npt.NDArray[np.int64]
    """Offset of each frame's first byte in ``buf``."""
    caplen: npt.NDArray[np.int64]
    """Captured bytes per frame."""
    t_ns: npt.NDArray[np.int64]
    """Capture time, UTC nanoseconds."""
    frame_no: npt.NDArray[np.int64]
    """Frame number, 1-based."""
    file_offset: npt.NDArray[np.int64]
    """Byte offset of each frame's record in the file or stream."""
    linktype: npt.NDArray[np.int32]
    """Link type per frame."""
    problems: list[FrameProblem] = field(default_factory=list)
    """Frames and records lost in this part of the capture."""
    bytes_consumed: int = 0
    """Stream position after this chunk (for progress)."""

    def __len__(self) -> int:
        return int(self.start.shape[0])


def _u32_view(buf: bytes, endian: str) -> npt.NDArray[np.uint32]:
    n = max(len(buf) - 3, 0)
    return np.ndarray((n,), dtype=endian + "u4", buffer=buf, offset=0, strides=(1,))


def _u16_view(buf: bytes, endian: str) -> npt.NDArray[np.uint16]:
    n = max(len(buf) - 1, 0)
    return np.ndarray((n,), dtype=endian + "u2", buffer=buf, offset=0, strides=(1,))


def _ts_to_ns(ts: npt.NDArray[np.uint64], iface: Interface) -> npt.NDArray[np.int64]:
    """pcapng timestamps (units of the interface's resolution) to UTC ns."""
    exp = iface.tsresol & 0x7F
    if iface.tsresol & 0x80:
        whole = (ts >> np.uint64(exp)).astype(np.int64) * NS_PER_S
        frac = (ts & np.uint64((1 << exp) - 1)).astype(np.float64) * (NS_PER_S / 2.0**exp)
        out = whole + frac.astype(np.int64)
    elif exp <= 9:
        out = ts.astype(np.int64) * 10 ** (9 - exp)
    else:
        out = (ts // np.uint64(10 ** (exp - 9))).astype(np.int64)
    return out + iface.tsoffset_s * NS_PER_S


RECORD_HEADER = 16
"""Bytes of a pcap record header: seconds, fraction, captured length, original length."""
RECORD_CAPLEN_AT = 8
"""Offset of the captured length in a pcap record header."""
FAST_MIN_BYTES = 64 * 1024
"""Below this many buffered bytes pcap records are found one by one.

The numpy walk (:func:`find_pcap_records`) parses a pcap of realistic frame
sizes (60–1,500 bytes) about 1.4 times faster than the record loop
(``bench/bench_capture.py``); pcapng blocks are always found one by one (a
numpy walk over them did not win there)."""
SLOW_RECORDS = 4096
"""Records found one by one after the numpy walk stopped early (then it is tried again)."""
MAX_REPAIRS = 16
"""Segments re-walked from a verified position before the walk gives up on a buffer."""


def _step(
    u32: npt.NDArray[np.uint32], p: npt.NDArray[np.int64], end: int
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """One pcap record at each offset in ``p``.

    Returns (offset of the next one, this one is whole and plausible, this one
    is plausible but cut by ``end``).
    """
    length = u32[p + RECORD_CAPLEN_AT].astype(np.int64)
    nxt = p + RECORD_HEADER + length
    plausible = length <= MAX_CAPLEN
    return nxt, plausible & (nxt <= end), plausible & (nxt > end)


def _lockstep(
    u32: npt.NDArray[np.uint32],
    starts: npt.NDArray[np.int64],
    seg_end: npt.NDArray[np.int64],
    end: int,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Walk the record chains from ``starts`` in lock step until each leaves its segment.

    Returns (grid of record offsets, one row per step and one column per
    chain, -1 where none; the offset where each chain crossed its segment end
    or met a record cut by the buffer end, or -1 when it met an implausible
    record first).
    """
    k = len(starts)
    at = starts.copy()
    crossing = np.full(k, -1, np.int64)
    rows: list[npt.NDArray[np.int64]] = []
    idx = np.flatnonzero(starts >= 0)
    while len(idx):
        p = at[idx]
        nxt, good, cut = _step(u32, p, end)
        row = np.full(k, -1, np.int64)
        row[idx] = np.where(good, p, -1)
        rows.append(row)
        at[idx] = nxt
        crossed = good & (nxt >= seg_end[idx])
        crossing[idx[crossed]] = nxt[crossed]
        # A plausible record cut by the end of the buffer ends its chain cleanly.
        crossing[idx[cut]] = p[cut]
        idx = idx[good & ~crossed]
    grid = np.stack(rows) if rows else np.full((0, k), -1, np.int64)
    return grid, crossing


def find_pcap_records(
    buf: bytes, endian: str, pos: int, end: int, mean_record: float
) -> tuple[npt.NDArray[np.int64], int]:
    """Offsets of consecutive pcap records from ``pos`` (a known record start), found with numpy.

    A record's offset depends on every record before it, so one walk is
    sequential. Instead the buffer is cut into segments; a record start is
    guessed near each segment start (the high half of its seconds field equal
    to the first record's, and a plausible length), and all segments are
    walked in lock step, one numpy gather per step. Segment ``k``'s walk is
    kept only if segment ``k-1``'s verified walk lands exactly on its start;
    a segment whose guess was wrong is walked again from that landing point.
    So every offset returned is on the true chain from ``pos``. The walk
    stops at a corrupt record or a record cut by the end of the buffer; the
    caller continues from the returned position record by record.

    Args:
        buf: the buffer.
        endian: ``"<"`` or ``">"``.
        pos: offset of a record header known to be on the chain.
        end: end of the valid data.
        mean_record: typical record size so far, bytes (sizes the segments).

    Returns:
        (record offsets, offset of the first record not returned).
    """
    none = np.empty(0, np.int64)
    if end - pos < FAST_MIN_BYTES:
        return none, pos
    u32 = _u32_view(buf, endian)
    u16 = _u16_view(buf, endian)
    seg_len = int(max(4096, 32 * mean_record))
    window = int(min(seg_len // 2, max(128, 3 * mean_record)))
    # The last window must end inside the buffer.
    k = (end - pos - window - RECORD_HEADER) // seg_len
    if k < 2:
        return none, pos
    seg = pos + np.arange(k, dtype=np.int64) * seg_len
    seg_end = seg + seg_len
    # The last chain stops where a full record header no longer fits.
    seg_end[-1] = end - RECORD_HEADER + 1
    rows = np.arange(k - 1)
    high = int(u32[pos]) >> 16
    high_at = 2 if endian == "<" else 0
    # Row j: the window after segment j+1's start, one u16 per byte offset.
    windows = np.lib.stride_tricks.as_strided(
        u16[int(seg[1]) + high_at :],
        shape=(k - 1, window),
        strides=(seg_len, 1),
        writeable=False,
    )
    match = windows == high
    first = match.argmax(axis=1)
    guess = seg[1:] + first
    length = u32[guess + RECORD_CAPLEN_AT].astype(np.int64)
    plausible = match[rows, first] & (length <= MAX_CAPLEN) & (u32[guess + 12] >= length)
    starts = np.concatenate(([pos], np.where(plausible, guess, -1)))
    grid, crossing = _lockstep(u32, starts, seg_end, end)
    redone: dict[int, npt.NDArray[np.int64]] = {}
    n_ok = 0
    for _ in range(MAX_REPAIRS + 1):
        chained = crossing >= 0
        chained[1:] &= crossing[:-1] == starts[1:]
        n_ok = int(np.cumprod(chained).sum())
        if n_ok in (0, k) or starts[n_ok] == crossing[n_ok - 1]:
            break
        # Chain n_ok started off the true chain: walk it again from where it must start.
        one = np.array([crossing[n_ok - 1]], np.int64)
        sub, cross = _lockstep(u32, one, seg_end[n_ok : n_ok + 1], end)
        starts[n_ok] = one[0]
        crossing[n_ok] = cross[0]
        column = sub[:, 0]
        redone[n_ok] = column[column >= 0]
    if n_ok == 0:
        return none, pos
    if not redone:
        offsets = grid[:, :n_ok].T.ravel()
        return offsets[offsets >= 0], int(crossing[n_ok - 1])
    parts = []
    for j in range(n_ok):
        if j in redone:
            parts.append(redone[j])
        else:
            column = grid[:, j]
            parts.append(column[column >= 0])
    return np.concatenate(parts), int(crossing[n_ok - 1])


class CaptureParser:
    """Push parser for pcap and pcapng streams.

    Args:
        name: how to name the capture in messages (file name, ``<stdin>``).

    Raises (from :meth:`next_chunk`):
        CaptureFormatError: the stream does not start with a pcap or pcapng
            header, or a pcapng section header is unreadable.
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self.format: str | None = None
        """``"pcap"`` or ``"pcapng"`` once the header has been read."""
        self.interfaces: list[Interface] = []
        self._buf = b""
        self._pos = 0
        self._base = 0
        self._frame_no = 0
        self._endian = "<"
        self._ts_scale = 1000
        self._resync_from: int | None = None
        self._pending: tuple[int, str] | None = None
        self._mean_record = 256.0

    # -- input ----------------------------------------------------------------------

    def feed(self, data: bytes) -> None:
        """Append bytes read from the stream."""
        if self._pos:
            self._base += self._pos
            self._buf = self._buf[self._pos :] + data
            self._pos = 0
        else:
            self._buf += data

    def refeed(self, data: bytes) -> None:
        """Replace the unconsumed bytes by ``data``, which starts with them (read again).

        For a seekable input: re-reading the few unconsumed bytes along with the
        next block costs less than copying the whole block behind them.

        Raises:
            ValueError: ``data`` is shorter than the unconsumed bytes.
        """
        if len(data) < self.buffered:
            raise ValueError(
                f"refeed needs at least the {self.buffered} unconsumed bytes, got {len(data)}"
            )
        self._base += self._pos
        self._buf = data
        self._pos = 0

    @property
    def buffered(self) -> int:
        """Bytes fed but not yet consumed."""
        return len(self._buf) - self._pos

    @property
    def position(self) -> int:
        """Stream offset of the next unread byte."""
        return self._base + self._pos

    # -- output ---------------------------------------------------------------------

    def next_chunk(self, final: bool = False, max_frames: int = 65_536) -> Chunk | None:
        """The next run of complete frames, or None when more input is needed.

        With ``final`` the stream has ended: a partial record becomes a
        problem, and None means nothing is left.
        """
        if self.format is None and not self._read_file_header(final):
            return None
        if self.format == "pcap":
            return self._chunk_pcap(final, max_frames)
        return self._chunk_pcapng(final, max_frames)

    # -- file header ----------------------------------------------------------------

    def _read_file_header(self, final: bool) -> bool:
        buf = self._buf
        if len(buf) < 4:
            if final:
                raise CaptureFormatError(
                    f"{self.name}: empty or truncated capture ({len(buf)} bytes, no file header)"
                )
            return False
        le = struct.unpack_from("<I", buf, 0)[0]
        be = struct.unpack_from(">I", buf, 0)[0]
        if le == PCAPNG_SHB:
            self.format = "pcapng"
            return True
        for magic, endian in ((le, "<"), (be, ">")):
            if magic in (PCAP_MAGIC_US, PCAP_MAGIC_NS):
                if len(buf) < 24:
                    if final:
                        raise CaptureFormatError(
                            f"{self.name}: pcap file header truncated ({len(buf)} of 24 bytes)"
                        )
                    return False
                self._endian = endian
                self._ts_scale = 1000 if magic == PCAP_MAGIC_US else 1
                network = struct.unpack_from(endian + "I", buf, 20)[0]
                self.interfaces = [Interface(network & 0x0FFFFFFF)]
                self.format = "pcap"
                self._pos = 24
                return True
        raise CaptureFormatError(
            f"{self.name}: byte 0: not a pcap or pcapng file (magic 0x{le:08x})"
        )

    # -- classic pcap ---------------------------------------------------------------

    def _pcap_plausible(self, buf: bytes, p: int) -> bool:
        _, frac, incl, orig = struct.unpack_from(self._endian + "IIII", buf, p)
        frac_max = 1_000_000 if self._ts_scale == 1000 else NS_PER_S
        return bool(0 < incl <= MAX_CAPLEN and incl <= orig and frac < frac_max)

    def _resync_pcap(self, buf: bytes, pos: int, end: int, final: bool) -> int | None:
        """Offset of the next plausible record after a corrupt one, or None (need more)."""
        u32 = _u32_view(buf, self._endian)
        lo, hi = pos + 1, end - 16
        if hi >= lo:
            p = np.arange(lo, hi + 1)
            incl = u32[p + 8].astype(np.int64)
            frac = u32[p + 4]
            frac_max = 1_000_000 if self._ts_scale == 1000 else NS_PER_S
            ok = (incl > 0) & (incl <= MAX_CAPLEN) & (u32[p + 12] >= incl) & (frac < frac_max)
            cand: int
            for cand in p[ok].tolist():
                nxt = cand + 16 + int(u32[cand + 8])
                if nxt == end and final:
                    return cand
                if nxt + 16 <= end and self._pcap_plausible(buf, nxt):
                    return cand
        if final or end - pos > RESYNC_LIMIT:
            return end
        return None

    def _resync_problem(self, pos: int, found: int, end: int) -> FrameProblem:
        """The problem for the corrupt record at ``pos``, now that the search ended at ``found``."""
        assert self._pending is not None
        frame_no, detail = self._pending
        self._pending = None
        if found >= end:
            detail += (
                f"; no plausible record follows, rest of the capture ({end - pos} bytes) skipped"
            )
        else:
            detail += f"; skipped {found - pos} bytes to the next plausible record"
        return FrameProblem(R_CORRUPT, frame_no, self._base + pos, detail)

    def _chunk_pcap(self, final: bool, max_frames: int) -> Chunk | None:
        buf = self._buf
        end = len(buf)
        pos = self._pos
        problems: list[FrameProblem] = []
        counter = self._frame_no
        offs: list[int] = []
        lost_at: list[int] = []
        if self._resync_from is not None:
            found = self._resync_pcap(buf, pos, end, final)
            if found is None:
                return None
            problems.append(self._resync_problem(pos, found, end))
            pos = found
            self._resync_from = None
        fast = np.empty(0, np.int64)
        budget = max_frames
        if self._resync_from is None and end - pos >= FAST_MIN_BYTES:
            # Look only as far as max_frames records probably reach.
            region = min(end, pos + int(max_frames * self._mean_record * 1.25) + FAST_MIN_BYTES)
            fast, pos = find_pcap_records(buf, self._endian, pos, region, self._mean_record)
            if len(fast) > 1:
                self._mean_record = (pos - int(fast[0])) / len(fast)
            if len(fast) > max_frames:
                pos = int(fast[max_frames])
                fast = fast[:max_frames]
            if len(fast) and pos >= region - MAX_CAPLEN - 16:
                budget = len(fast)  # the walk reached its region: the next call goes on
            else:
                budget = min(max_frames, len(fast) + SLOW_RECORDS)
        n_fast = len(fast)
        append = offs.append
        unpack = struct.Struct(self._endian + "I").unpack_from
        while n_fast + len(offs) < budget and pos + RECORD_HEADER <= end:
            incl = unpack(buf, pos + RECORD_CAPLEN_AT)[0]
            if incl > MAX_CAPLEN:
                lost_at.append(n_fast + len(offs))
                self._pending = (
                    counter + n_fast + len(offs) + len(lost_at),
                    f"record header says {incl} captured bytes (more than {MAX_CAPLEN})",
                )
                found = self._resync_pcap(buf, pos, end, final)
                if found is None:
                    self._resync_from = pos
                    break
                problems.append(self._resync_problem(pos, found, end))
                pos = found
                continue
            if pos + RECORD_HEADER + incl > end:
                break
            append(pos)
            pos += RECORD_HEADER + incl
        n_rec = n_fast + len(offs)
        if final and self._resync_from is None and pos < end and n_rec < budget:
            lost_at.append(n_rec)
            left = end - pos - 16
            detail = (
                f"record header truncated ({end - pos} of 16 bytes)"
                if left < 0
                else f"record truncated: header says "
                f"{unpack(buf, pos + 8)[0]} bytes, {left} left in the file"
            )
            number = counter + n_rec + len(lost_at)
            problems.append(FrameProblem(R_TRUNCATED, number, self._base + pos, detail))
            pos = end
        self._pos = pos
        self._frame_no = counter + n_rec + len(lost_at)
        if not n_rec and not problems:
            return None
        o = np.concatenate((fast, np.asarray(offs, np.int64))) if offs else fast
        u32 = _u32_view(buf, self._endian)
        sec = u32[o].astype(np.int64)
        frac = u32[o + 4].astype(np.int64)
        caplen = u32[o + 8].astype(np.int64)
        index = np.arange(len(o), dtype=np.int64)
        numbers = counter + 1 + index
        if lost_at:
            numbers += np.searchsorted(np.asarray(lost_at), index, side="right")
        chunk = Chunk(
            buf=buf,
            start=o + 16,
            caplen=caplen,
            t_ns=sec * NS_PER_S + frac * self._ts_scale,
            frame_no=numbers,
            file_offset=o + self._base,
            linktype=np.full(len(o), self.interfaces[0].linktype, np.int32),
            problems=problems,
            bytes_consumed=self._base + pos,
        )
        return _drop_empty(chunk)

    # -- pcapng ---------------------------------------------------------------------

    def _read_shb(self, buf: bytes, pos: int, end: int) -> int | None:
        """Parse a section header at ``pos``; its length, or None when incomplete.

        Raises:
            CaptureFormatError: unreadable byte-order magic or version in the first section.
        """
        if pos + 12 > end:
            return None
        bom = buf[pos + 8 : pos + 12]
        if bom == struct.pack("<I", PCAPNG_BYTE_ORDER_MAGIC):
            endian = "<"
        elif bom == struct.pack(">I", PCAPNG_BYTE_ORDER_MAGIC):
            endian = ">"
        else:
            raise CaptureFormatError(
                f"bad pcapng byte-order magic {bom.hex()} (expected 1a2b3c4d in either byte order)"
            )
        blen = struct.unpack_from(endian + "I", buf, pos + 4)[0]
        if blen < 28 or blen % 4 or blen > MAX_BLOCK:
            raise CaptureFormatError(f"pcapng section header length {blen} is invalid")
        if pos + blen > end:
            return None
        if struct.unpack_from(endian + "I", buf, pos + blen - 4)[0] != blen:
            raise CaptureFormatError(
                f"pcapng section header: trailing length does not match {blen}"
            )
        major = struct.unpack_from(endian + "H", buf, pos + 12)[0]
        if major != 1:
            raise CaptureFormatError(f"pcapng major version {major} is not supported (expected 1)")
        self._endian = endian
        self.interfaces = []
        return int(blen)

    def _read_idb(self, buf: bytes, pos: int, blen: int) -> None:
        e = self._endian
        linktype = struct.unpack_from(e + "H", buf, pos + 8)[0]
        iface = Interface(linktype)
        opt = pos + 16
        stop = pos + blen - 4
        while opt + 4 <= stop:
            code, length = struct.unpack_from(e + "HH", buf, opt)
            if code == OPT_END:
                break
            value = opt + 4
            if value + length > stop:
                raise CaptureFormatError(f"interface option {code} runs past the block end")
            if code == OPT_IF_TSRESOL and length >= 1:
                iface.tsresol = buf[value]
                exp = iface.tsresol & 0x7F
                if (iface.tsresol & 0x80 and exp > 63) or (not iface.tsresol & 0x80 and exp > 19):
                    raise CaptureFormatError(f"if_tsresol 0x{iface.tsresol:02x} is out of range")
            elif code == OPT_IF_TSOFFSET and length >= 8:
                iface.tsoffset_s = struct.unpack_from(e + "q", buf, value)[0]
            opt = value + ((length + 3) & ~3)
        self.interfaces.append(iface)

    def _block_ok(self, buf: bytes, p: int, end: int) -> bool:
        btype, blen = struct.unpack_from(self._endian + "II", buf, p)
        if btype not in _KNOWN_BLOCKS or blen < 12 or blen % 4 or blen > MAX_BLOCK:
            return False
        if p + blen > end:
            return False
        return bool(struct.unpack_from(self._endian + "I", buf, p + blen - 4)[0] == blen)

    def _resync_pcapng(self, buf: bytes, pos: int, end: int, final: bool) -> int | None:
        for p in range(pos + 4, end - 11, 4):
            if self._block_ok(buf, p, end):
                return p
        if final or end - pos > RESYNC_LIMIT:
            return end
        return None

    def _chunk_pcapng(self, final: bool, max_frames: int) -> Chunk | None:
        buf = self._buf
        end = len(buf)
        pos = self._pos
        problems: list[FrameProblem] = []
        frames: list[int] = []
        kinds: list[int] = []
        lost_at: list[int] = []
        counter = self._frame_no

        def lose(reason: str, at: int, detail: str) -> None:
            lost_at.append(len(frames))
            number = counter + len(frames) + len(lost_at)
            problems.append(FrameProblem(reason, number, self._base + at, detail))

        if self._resync_from is not None:
            found = self._resync_pcapng(buf, pos, end, final)
            if found is None:
                return None
            pos = found
            self._resync_from = None
        head = struct.Struct(self._endian + "II")
        tail = struct.Struct(self._endian + "I")
        while len(frames) < max_frames and pos + 12 <= end:
            if struct.unpack_from("<I", buf, pos)[0] == PCAPNG_SHB:
                if frames:
                    break  # a chunk never spans sections: the byte order may change
                try:
                    blen = self._read_shb(buf, pos, end)
                except CaptureFormatError as err:
                    if self._base + pos == 0:
                        raise CaptureFormatError(f"{self.name}: byte 0: {err}") from err
                    # A later section header: lose this section's start, look for the next block.
                    problems.append(FrameProblem(R_BAD_BLOCK, 0, self._base + pos, str(err)))
                    found = self._resync_pcapng(buf, pos, end, final)
                    if found is None:
                        self._resync_from = pos
                        break
                    pos = found
                    continue
                if blen is None:
                    if final:
                        raise CaptureFormatError(
                            f"{self.name}: byte {self._base + pos}: capture ends inside "
                            "a pcapng section header"
                        )
                    break
                head = struct.Struct(self._endian + "II")
                tail = struct.Struct(self._endian + "I")
                pos += blen
                continue
            btype, blen = head.unpack_from(buf, pos)
            bad = None
            if blen < 12 or blen % 4 or blen > MAX_BLOCK:
                bad = f"pcapng block type 0x{btype:08x} has invalid length {blen}"
            elif pos + blen > end:
                if not final:
                    break
                bad = (
                    f"pcapng block truncated: {blen} bytes announced, {end - pos} left in the file"
                )
            elif tail.unpack_from(buf, pos + blen - 4)[0] != blen:
                bad = f"pcapng block type 0x{btype:08x}: trailing length does not match {blen}"
            if bad is not None:
                reason = R_TRUNCATED if "truncated" in bad else R_BAD_BLOCK
                if btype in (BT_EPB, BT_PB, BT_SPB):
                    lose(reason, pos, bad)
                else:
                    problems.append(FrameProblem(reason, 0, self._base + pos, bad))
                found = self._resync_pcapng(buf, pos, end, final)
                if found is None:
                    self._resync_from = pos
                    break
                pos = found
                continue
            if btype in (BT_EPB, BT_PB):
                if blen < 32:
                    lose(R_BAD_BLOCK, pos, f"packet block of {blen} bytes is shorter than 32")
                else:
                    frames.append(pos)
                    kinds.append(btype)
            elif btype == BT_IDB:
                try:
                    if blen < 20:
                        raise CaptureFormatError(f"block of {blen} bytes is too short")
                    self._read_idb(buf, pos, blen)
                except CaptureFormatError as err:
                    # Keep the numbering: packets name interfaces by index.
                    self.interfaces.append(Interface(-1))
                    problems.append(
                        FrameProblem(R_BAD_BLOCK, 0, self._base + pos, f"interface block: {err}")
                    )
            elif btype == BT_SPB:
                lose(R_NO_TIMESTAMP, pos, "simple packet block carries no timestamp")
            elif btype not in _SKIPPED_BLOCKS:
                problems.append(
                    FrameProblem(
                        R_UNKNOWN_BLOCK,
                        0,
                        self._base + pos,
                        f"unknown pcapng block type 0x{btype:08x} ({blen} bytes) skipped",
                    )
                )
            pos += blen
        n_rec = len(frames)
        if final and self._resync_from is None and n_rec < max_frames and 0 < end - pos < 12:
            problems.append(
                FrameProblem(
                    R_TRUNCATED,
                    0,
                    self._base + pos,
                    f"capture ends inside a block header ({end - pos} bytes left)",
                )
            )
            pos = end
        self._pos = pos
        self._frame_no = counter + n_rec + len(lost_at)
        if not n_rec and not problems:
            return None
        return self._pcapng_spans(buf, frames, kinds, lost_at, counter, problems, pos)

    def _pcapng_spans(
        self,
        buf: bytes,
        frames: list[int],
        kinds: list[int],
        lost_at: list[int],
        counter: int,
        problems: list[FrameProblem],
        pos: int,
    ) -> Chunk:
        o = np.asarray(frames, np.int64)
        e = self._endian
        u32 = _u32_view(buf, e)
        u16 = _u16_view(buf, e)
        is_pb = np.asarray(kinds, np.int64) == BT_PB
        blen = u32[o + 4].astype(np.int64)
        iface = np.where(is_pb, u16[o + 8], u32[o + 8]).astype(np.int64)
        ts = (u32[o + 12].astype(np.uint64) << np.uint64(32)) | u32[o + 16].astype(np.uint64)
        caplen = u32[o + 20].astype(np.int64)
        index = np.arange(len(o), dtype=np.int64)
        numbers = counter + 1 + index
        if lost_at:
            numbers += np.searchsorted(np.asarray(lost_at), index, side="right")
        t_ns = np.zeros(len(o), np.int64)
        linktype = np.full(len(o), -1, np.int32)
        for k, itf in enumerate(self.interfaces):
            sel = iface == k
            if sel.any():
                t_ns[sel] = _ts_to_ns(ts[sel], itf)
                linktype[sel] = itf.linktype
        bad_iface = linktype < 0
        too_long = caplen > blen - 32
        keep = ~(bad_iface | too_long)
        for i in np.flatnonzero(~keep).tolist():
            if bad_iface[i]:
                detail = (
                    f"packet names interface {int(iface[i])}, but the section defines "
                    f"{len(self.interfaces)} usable interface(s)"
                )
                reason = R_INTERFACE
            else:
                detail = (
                    f"captured length {int(caplen[i])} exceeds the block "
                    f"({int(blen[i]) - 32} data bytes)"
                )
                reason = R_TRUNCATED
            problems.append(FrameProblem(reason, int(numbers[i]), self._base + int(o[i]), detail))
        problems.sort(key=lambda p: p.byte_offset)
        chunk = Chunk(
            buf=buf,
            start=(o + 28)[keep],
            caplen=caplen[keep],
            t_ns=t_ns[keep],
            frame_no=numbers[keep],
            file_offset=(o + self._base)[keep],
            linktype=linktype[keep],
            problems=problems,
            bytes_consumed=self._base + pos,
        )
        return _drop_empty(chunk)


def _drop_empty(chunk: Chunk) -> Chunk:
    """Turn zero-length frames into problems."""
    empty = chunk.caplen == 0
    if not empty.any():
        return chunk
    for i in np.flatnonzero(empty).tolist():
        chunk.problems.append(
            FrameProblem(
                R_EMPTY, int(chunk.frame_no[i]), int(chunk.file_offset[i]), "zero-length frame"
            )
        )
    keep = ~empty
    chunk.start = chunk.start[keep]
    chunk.caplen = chunk.caplen[keep]
    chunk.t_ns = chunk.t_ns[keep]
    chunk.frame_no = chunk.frame_no[keep]
    chunk.file_offset = chunk.file_offset[keep]
    chunk.linktype = chunk.linktype[keep]
    return chunk


def iter_chunks(data: bytes, name: str = "<bytes>", max_frames: int = 65_536) -> list[Chunk]:
    """Every chunk of a complete in-memory capture.

    Raises:
        CaptureFormatError: the data is not a capture at all.
    """
    parser = CaptureParser(name)
    parser.feed(data)
    out: list[Chunk] = []
    while True:
        chunk = parser.next_chunk(final=True, max_frames=max_frames)
        if chunk is None:
            return out
        out.append(chunk)


class PcapWriter:
    """Write frames to a classic pcap stream (nanosecond timestamps, little-endian).

    Args:
        stream: a binary file opened for writing.
        linktype: link-layer type of every frame (127 radiotap by default).
        snaplen: the snap length written in the file header.
    """

    def __init__(self, stream: BinaryIO, linktype: int = 127, snaplen: int = 65_535) -> None:
        self.stream = stream
        stream.write(struct.pack("<IHHiIII", PCAP_MAGIC_NS, 2, 4, 0, 0, snaplen, linktype))

    def write(self, t_ns: int, frame: bytes) -> None:
        """Append one frame captured at ``t_ns`` (UTC nanoseconds)."""
        sec, nsec = divmod(int(t_ns), NS_PER_S)
        self.stream.write(struct.pack("<IIII", sec, nsec, len(frame), len(frame)))
        self.stream.write(frame)
