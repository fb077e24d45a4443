"""Write the capture test files derived from the real meshid capture.

Run from anywhere: ``python tests/data/make_broken_captures.py``. Each output
is named for what it proves; the ``broken_*`` files carry exactly one defect.
The meshid capture has 3 frames of 56-byte radiotap + 802.11 beacon/probe.
"""

from __future__ import annotations

import struct
from pathlib import Path

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "ieee802.11_meshid.pcap"


def read_records(path: Path) -> tuple[bytes, list[tuple[int, int, bytes]]]:
    """The pcap file header and (seconds, microseconds, frame) records."""
    data = path.read_bytes()
    header, pos, records = data[:24], 24, []
    while pos + 16 <= len(data):
        sec, usec, incl, _ = struct.unpack_from("<IIII", data, pos)
        records.append((sec, usec, data[pos + 16 : pos + 16 + incl]))
        pos += 16 + incl
    return header, records


def pcap(records: list[tuple[int, int, bytes]], endian: str = "<", linktype: int = 127) -> bytes:
    out = bytearray(struct.pack(endian + "IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, linktype))
    for sec, usec, frame in records:
        out += struct.pack(endian + "IIII", sec, usec, len(frame), len(frame)) + frame
    return bytes(out)


def block(endian: str, btype: int, body: bytes) -> bytes:
    body += bytes(-len(body) % 4)
    n = len(body) + 12
    return struct.pack(endian + "II", btype, n) + body + struct.pack(endian + "I", n)


def shb(endian: str, magic: int = 0x1A2B3C4D) -> bytes:
    return block(endian, 0x0A0D0D0A, struct.pack(endian + "IHHq", magic, 1, 0, -1))


def idb(endian: str, linktype: int, tsresol: int | None = None) -> bytes:
    opts = b""
    if tsresol is not None:
        opts = struct.pack(endian + "HHB3x", 9, 1, tsresol) + struct.pack(endian + "HH", 0, 0)
    return block(endian, 1, struct.pack(endian + "HHI", linktype, 0, 65535) + opts)


def epb(endian: str, iface: int, ts: int, frame: bytes) -> bytes:
    head = struct.pack(endian + "IIIII", iface, ts >> 32, ts & 0xFFFFFFFF, len(frame), len(frame))
    return block(endian, 6, head + frame)


def pcapng_us(records: list[tuple[int, int, bytes]], endian: str = "<") -> bytes:
    out = shb(endian) + idb(endian, 127)
    for sec, usec, frame in records:
        out += epb(endian, 0, sec * 1_000_000 + usec, frame)
    return out


def with_it_len(frame: bytes, it_len: int) -> bytes:
    return frame[:2] + struct.pack("<H", it_len) + frame[4:]


def main() -> None:
    _, recs = read_records(SOURCE)
    assert len(recs) == 3
    out: dict[str, bytes] = {}

    # Good files in other container variants: byte orders, pcapng, several interfaces.
    out["meshid_big_endian.pcap"] = pcap(recs, ">")
    out["meshid_little_endian.pcapng"] = pcapng_us(recs, "<")
    out["meshid_big_endian.pcapng"] = pcapng_us(recs, ">")
    # Interface 0: radiotap with nanosecond stamps; interface 1: bare 802.11 (no signal)
    # with the default microsecond stamps. Frames alternate between them.
    multi = shb("<") + idb("<", 127, 9) + idb("<", 105)
    for k, (sec, usec, frame) in enumerate(recs):
        multi += epb("<", 0, (sec * 1_000_000 + usec) * 1000, frame)
        multi += epb("<", 1, sec * 1_000_000 + usec + 1, frame[56:])
        del k
    out["two_interfaces_radiotap_ns_and_80211_us.pcapng"] = multi

    # Broken files: one defect each.
    full = pcap(recs)
    out["broken_truncated_file.pcap"] = full[:-40]
    cut = [recs[0], (recs[1][0], recs[1][1], recs[1][2][:30]), recs[2]]
    out["broken_record_cut_inside_radiotap.pcap"] = pcap(cut)
    big = [recs[0], (recs[1][0], recs[1][1], with_it_len(recs[1][2], 500)), recs[2]]
    out["broken_it_len_larger_than_packet.pcap"] = pcap(big)
    zero = [recs[0], (recs[1][0], recs[1][1], b""), recs[2]]
    out["broken_zero_length_frame.pcap"] = pcap(zero)
    corrupt = bytearray(full)
    second = 24 + 16 + len(recs[0][2])
    struct.pack_into("<I", corrupt, second + 8, 0x7FFFFFFF)
    out["broken_corrupt_record_header.pcap"] = bytes(corrupt)
    out["broken_not_a_capture.pcap"] = b"GIF89a" + full[6:]
    unknown = shb("<") + idb("<", 127)
    for k, (sec, usec, frame) in enumerate(recs):
        if k == 1:
            unknown += block("<", 0x0000_0777, b"not a block type anyone defined")
        unknown += epb("<", 0, sec * 1_000_000 + usec, frame)
    out["broken_unknown_block.pcapng"] = unknown
    out["broken_bad_byte_order_magic.pcapng"] = shb("<", 0x11223344) + pcapng_us(recs)[28:]
    second_section = pcapng_us(recs[:1]) + shb("<", 0x11223344) + idb("<", 127)
    for sec, usec, frame in recs[1:]:
        second_section += epb("<", 0, sec * 1_000_000 + usec, frame)
    out["broken_bad_byte_order_magic_second_section.pcapng"] = second_section

    for name, data in out.items():
        (HERE / name).write_bytes(data)
        print(f"{name}: {len(data)} bytes")


if __name__ == "__main__":
    main()
