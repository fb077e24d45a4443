"""An independent radiotap and 802.11 writer for tests.

Written from the radiotap.org field table, separately from the parser, so a
round trip checks the parser against the format rather than against itself.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

# bit -> (alignment, size); the radiotap.org table for bits 0–27.
SPEC: dict[int, tuple[int, int]] = {
    0: (8, 8), 1: (1, 1), 2: (1, 1), 3: (2, 4), 4: (2, 2), 5: (1, 1), 6: (1, 1),
    7: (2, 2), 8: (2, 2), 9: (2, 2), 10: (1, 1), 11: (1, 1), 12: (1, 1), 13: (1, 1),
    14: (2, 2), 15: (2, 2), 16: (1, 1), 17: (1, 1), 18: (4, 8), 19: (1, 3), 20: (4, 8),
    21: (2, 12), 22: (8, 12), 23: (2, 12), 24: (2, 12), 25: (2, 6), 26: (1, 1), 27: (2, 4),
}  # fmt: skip


@dataclass
class RtNamespace:
    """A radiotap namespace: field bit -> raw little-endian value bytes."""

    fields: dict[int, bytes] = field(default_factory=dict)


@dataclass
class VendorNs:
    """A vendor namespace: its header and opaque data (with arbitrary present bits)."""

    oui: int
    subns: int
    data: bytes
    present_bits: int = 0


Namespace = RtNamespace | VendorNs


def value(bit: int, number: int) -> bytes:
    """Encode ``number`` as the little-endian value of field ``bit`` (signed for s8 fields)."""
    size = SPEC[bit][1]
    if bit in (5, 6, 10):
        return struct.pack("<b", (number + 128) % 256 - 128)
    return (number % (1 << (8 * size))).to_bytes(size, "little")


def build(namespaces: list[Namespace], trailing: bytes = b"") -> bytes:
    """A radiotap header holding ``namespaces`` in order (the first must be radiotap)."""
    assert isinstance(namespaces[0], RtNamespace)
    words: list[int] = []
    for i, ns in enumerate(namespaces):
        word = 0
        if isinstance(ns, RtNamespace):
            for bit in ns.fields:
                word |= 1 << bit
        else:
            word = ns.present_bits & ((1 << 29) - 1)
        if i + 1 < len(namespaces):
            nxt = namespaces[i + 1]
            word |= (1 << 31) | (1 << (30 if isinstance(nxt, VendorNs) else 29))
        words.append(word)
    body = bytearray(struct.pack("<BBH", 0, 0, 0))
    for w in words:
        body += struct.pack("<I", w)
    for i, ns in enumerate(namespaces):
        if isinstance(ns, RtNamespace):
            for bit in sorted(ns.fields):
                align, size = SPEC[bit]
                while len(body) % align:
                    body.append(0)
                raw = ns.fields[bit]
                assert len(raw) == size
                body += raw
        else:
            body += ns.data
        if i + 1 < len(namespaces):
            nxt = namespaces[i + 1]
            if isinstance(nxt, VendorNs):
                while len(body) % 2:
                    body.append(0)
                body += nxt.oui.to_bytes(3, "big") + struct.pack("<BH", nxt.subns, len(nxt.data))
    body += trailing
    struct.pack_into("<H", body, 2, len(body))
    return bytes(body)


def dot11(
    type_subtype: int = 0x08,
    ta: int = 0x0211_2233_4455,
    seq: int = 1,
    frag: int = 0,
    retry: bool = False,
    payload: bytes = b"",
    fcs: bool = False,
) -> bytes:
    """An 802.11 frame: management/data get the 24-byte header; control frames their own."""
    ftype, subtype = type_subtype >> 4, type_subtype & 0xF
    fc = (ftype << 2) | (subtype << 4) | (0x0800 if retry else 0)
    addr1 = bytes.fromhex("ffffffffffff")
    ta_bytes = ta.to_bytes(6, "big")
    if ftype == 1:
        frame = struct.pack("<HH", fc, 0) + addr1
        if subtype not in (12, 13):
            frame += ta_bytes
    else:
        sc = (seq << 4) | frag
        frame = struct.pack("<HH", fc, 0) + addr1 + ta_bytes + addr1 + struct.pack("<H", sc)
    frame += payload
    if fcs:
        frame += b"\xde\xad\xbe\xef"
    return frame


def pcap(frames: list[tuple[int, bytes]], linktype: int = 127, big_endian: bool = False) -> bytes:
    """A classic pcap file (microsecond timestamps) with ``(t_ns, frame)`` records."""
    e = ">" if big_endian else "<"
    out = bytearray(struct.pack(e + "IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, linktype))
    for t_ns, frame in frames:
        sec, rest = divmod(t_ns, 1_000_000_000)
        out += struct.pack(e + "IIII", sec, rest // 1000, len(frame), len(frame)) + frame
    return bytes(out)


def _block(e: str, btype: int, body: bytes) -> bytes:
    body = body + bytes(-len(body) % 4)
    n = len(body) + 12
    return struct.pack(e + "II", btype, n) + body + struct.pack(e + "I", n)


def pcapng(
    interfaces: list[tuple[int, int | None]],
    packets: list[tuple[int, int, bytes]],
    big_endian: bool = False,
    extra_blocks: list[tuple[int, int, bytes]] | None = None,
) -> bytes:
    """A pcapng file: ``interfaces`` are ``(linktype, tsresol or None)``; ``packets`` are
    ``(interface, timestamp in the interface's units, frame)``. ``extra_blocks`` inserts
    ``(before packet index, block type, body)``."""
    e = ">" if big_endian else "<"
    out = bytearray(_block(e, 0x0A0D0D0A, struct.pack(e + "IHHq", 0x1A2B3C4D, 1, 0, -1)))
    for linktype, tsresol in interfaces:
        opts = b""
        if tsresol is not None:
            opts = struct.pack(e + "HHB3x", 9, 1, tsresol) + struct.pack(e + "HH", 0, 0)
        out += _block(e, 1, struct.pack(e + "HHI", linktype, 0, 65535) + opts)
    extras = sorted(extra_blocks or [], key=lambda x: x[0])
    for i, (iface, ts, frame) in enumerate(packets):
        for _, btype, body in [x for x in extras if x[0] == i]:
            out += _block(e, btype, body)
        hdr = struct.pack(e + "IIIII", iface, ts >> 32, ts & 0xFFFFFFFF, len(frame), len(frame))
        out += _block(e, 6, hdr + frame)
    return bytes(out)


def mac80211_header(rssi0: int, rssi1: int, freq_mhz: int = 2437, tsft_us: int = 0) -> bytes:
    """A two-chain header in Linux mac80211's layout (TSFT, flags, channel, combined, chains)."""
    combined = max(rssi0, rssi1)
    return build(
        [
            RtNamespace(
                {
                    0: value(0, tsft_us),
                    1: value(1, 0),
                    3: struct.pack("<HH", freq_mhz, 0x00A0),
                    5: value(5, combined),
                }
            ),
            RtNamespace({5: value(5, rssi0), 11: value(11, 0)}),
            RtNamespace({5: value(5, rssi1), 11: value(11, 1)}),
        ]
    )


def sweep_capture(
    n: int, span_s: float, start_ns: int = 1_700_000_000_000_000_000, emitters: int = 3
) -> bytes:
    """``n`` beacons from ``emitters`` transmitters over ``span_s`` seconds, two chains each,
    with the two signals a few dB apart (inside a typical field of view) and each
    transmitter's level steady within 3 dB (as from one place; a transmitter whose level
    jumps far below its own best is refused as possibly behind the antennas)."""
    frames = []
    for i in range(n):
        t_ns = start_ns + int(i * span_s * 1e9 / max(n - 1, 1))
        r0 = -50 - (i % 7) % 4
        r1 = r0 + (i % 5) - 2
        ta = 0x0200_0000_0000 + (i % emitters)
        frames.append(
            (t_ns, mac80211_header(r0, r1, tsft_us=i * 1000) + dot11(ta=ta, seq=i % 4096))
        )
    return pcap(frames)


STILL = ["--prove-motion", "0"]
"""Options for replaying a capture whose transmitters stand still (as these helpers'
do): on a fixed mount the motion rule refuses every bearing of a transmitter that never
moves, and the tests that replay one check something else."""
