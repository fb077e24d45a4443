"""The user-data samples in a pcap of RTPS traffic, written from the RTPS 2.x wire format.

Only what the DDS test needs: Ethernet (or Linux cooked) → IPv4 → UDP → RTPS
messages; DATA (0x15) and DATA_FRAG (0x16) submessages of user writers
(entity kind 0x02/0x03), reassembled, de-duplicated by (writer GUID, sequence
number), with their serialized payload as it went on the wire.
"""

from __future__ import annotations

import struct
from pathlib import Path

DATA, DATA_FRAG, INFO_TS = 0x15, 0x16, 0x09


def udp_payloads(path: Path) -> list[bytes]:
    """UDP payloads of every IPv4 packet in a classic pcap file (Ethernet or SLL link)."""
    raw = path.read_bytes()
    magic = raw[:4]
    endian = "<" if magic in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1") else ">"
    linktype = struct.unpack_from(endian + "I", raw, 20)[0]
    link_len = {1: 14, 113: 16}[linktype]
    out, off = [], 24
    while off + 16 <= len(raw):
        incl = struct.unpack_from(endian + "I", raw, off + 8)[0]
        pkt = raw[off + 16 : off + 16 + incl]
        off += 16 + incl
        ip = pkt[link_len:]
        if len(ip) < 20 or ip[0] >> 4 != 4 or ip[9] != 17:
            continue
        ihl = (ip[0] & 0x0F) * 4
        total = struct.unpack_from(">H", ip, 2)[0]
        out.append(bytes(ip[ihl + 8 : total]))
    return out


def user_samples(path: Path) -> dict[tuple[bytes, bytes, int], bytes]:
    """Serialized payloads of user DATA/DATA_FRAG by (guid prefix, writer id, sequence number)."""
    samples: dict[tuple[bytes, bytes, int], bytes] = {}
    frags: dict[tuple[bytes, bytes, int], dict[int, bytes]] = {}
    sizes: dict[tuple[bytes, bytes, int], int] = {}
    for msg in udp_payloads(path):
        if msg[:4] != b"RTPS":
            continue
        prefix = msg[8:20]
        off = 20
        while off + 4 <= len(msg):
            sub_id, flags = msg[off], msg[off + 1]
            e = "<" if flags & 1 else ">"
            length = struct.unpack_from(e + "H", msg, off + 2)[0]
            body = msg[off + 4 : off + 4 + length] if length else msg[off + 4 :]
            off += 4 + (length if length else len(body))
            if sub_id not in (DATA, DATA_FRAG):
                continue
            to_qos = struct.unpack_from(e + "H", body, 2)[0]
            writer = body[8:12]
            if writer[3] not in (0x02, 0x03):
                continue  # a built-in (discovery) writer
            hi, lo = struct.unpack_from(e + "iI", body, 12)
            key = (prefix, writer, (hi << 32) | lo)
            start = 4 + to_qos
            if sub_id == DATA:
                if flags & 0x02:  # inline QoS: a parameter list up to PID_SENTINEL
                    start = _skip_params(body, start, e)
                if flags & 0x04:  # serialized payload present
                    samples.setdefault(key, body[start:])
                continue
            first, count, frag_size, sample_size = struct.unpack_from(e + "IHHI", body, 20)
            if flags & 0x02:
                start = _skip_params(body, start, e)
            data = body[start:]
            parts = frags.setdefault(key, {})
            sizes[key] = sample_size
            for i in range(count):
                parts[first + i] = data[i * frag_size : (i + 1) * frag_size]
    for key, parts in frags.items():
        whole = b"".join(parts[i] for i in sorted(parts))[: sizes[key]]
        if len(whole) == sizes[key]:
            samples.setdefault(key, whole)
    return samples


def _skip_params(body: bytes, start: int, e: str) -> int:
    while True:
        pid, plen = struct.unpack_from(e + "HH", body, start)
        start += 4 + plen
        if pid == 1:  # PID_SENTINEL
            return start
