"""GeoNetworking and BTP-B framing of CPMs, and pcap files of such frames.

A CPM goes on the ITS-G5 air, or into an Ethernet capture, as

    Ethernet (type 0x8947) | GeoNetworking basic + common header | single-hop
    broadcast (SHB) extended header | BTP-B (destination port 2009) | CPM

(ETSI EN 302 636-4-1 for GeoNetworking, EN 302 636-5-1 for BTP). The station's
GeoNetworking address and Ethernet source are *locally administered* addresses
made from its station id (``02:00`` + the id's four bytes), never a device's MAC.
Bridges that take CPMs over UDP (``etsi_its_messages``-style) want either the bare
CPM or the BTP-B header and the CPM; :func:`split_datagram` reads all three forms.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from rfsas_hw.errors import CpmFormatError, DataFormatError
from rfsas_hw.sources.pcapfile import PcapWriter, iter_chunks
from rfsas_hw.v2x.timestamp import its_ms_from_utc_ns

__all__ = [
    "BTP_CPM_PORT",
    "ETHERTYPE_GEONET",
    "GeoPosition",
    "btp_b",
    "ethernet_frame",
    "read_cpm_file",
    "read_pcap_cpms",
    "split_datagram",
    "station_address",
    "write_pcap",
]

ETHERTYPE_GEONET = 0x8947
BTP_CPM_PORT = 2009
"""Well-known BTP port of the CPM (ETSI TS 103 248)."""
LINKTYPE_ETHERNET = 1
GN_VERSION = 1
_NH_COMMON = 1
_NH_BTP_B = 2
_HT_TSB = 5
_HST_SHB = 0
_LIFETIME_1S = (1 << 2) | 1
"""Lifetime multiplier 1 with base 1 s."""
_TC_DEFAULT = 0x02
_BASIC_LEN = 4
_COMMON_LEN = 8
_SHB_LEN = 28
_BTP_LEN = 4
_BROADCAST = b"\xff" * 6
_EXTENDED_LEN = {
    (5, 0): 28,
    (5, 1): 28,
    **{(ht, hst): 44 for ht in (3, 4) for hst in (0, 1, 2)},
}
"""Extended-header length by (header type, subtype), for the packets a CPM may arrive
in: single-hop broadcast 28 (source position vector, media-dependent data), multi-hop
topologically-scoped broadcast 28 (sequence number, reserved, position vector),
GeoBroadcast and GeoAnycast 44 (… and the destination area)."""


@dataclass(frozen=True, slots=True)
class GeoPosition:
    """The sender's position vector in the GeoNetworking header."""

    lat_deg: float
    lon_deg: float
    speed_mps: float = 0.0
    heading_deg: float = 0.0


def station_address(station_id: int) -> bytes:
    """A locally administered 6-byte address made from a station id (``02:00:`` + id)."""
    return b"\x02\x00" + struct.pack(">I", station_id & 0xFFFFFFFF)


def btp_b(payload: bytes, port: int = BTP_CPM_PORT) -> bytes:
    """``payload`` behind a BTP-B header (destination port, port info 0)."""
    return struct.pack(">HH", port, 0) + payload


def _geonet(
    payload: bytes, station_id: int, station_type: int, t_ns: int, where: GeoPosition
) -> bytes:
    """Basic, common and SHB headers around ``payload`` (a BTP-B packet)."""
    basic = bytes([(GN_VERSION << 4) | _NH_COMMON, 0, _LIFETIME_1S, 1])
    common = struct.pack(
        ">BBBBHBB",
        _NH_BTP_B << 4,
        (_HT_TSB << 4) | _HST_SHB,
        _TC_DEFAULT,
        0,  # flags: not mobile
        len(payload),
        1,  # maximum hop limit: single hop
        0,
    )
    gn_addr = struct.pack(">H", (1 << 15) | ((station_type & 0x1F) << 10)) + station_address(
        station_id
    )
    speed = max(-16384, min(16383, round(where.speed_mps * 100)))
    tst = its_ms_from_utc_ns(t_ns) & 0xFFFFFFFF
    pv = gn_addr + struct.pack(
        ">IiiHH",
        tst,
        round(where.lat_deg * 1e7),
        round(where.lon_deg * 1e7),
        # PAI bit (position accuracy indicator) cleared, then 15-bit signed speed
        speed & 0x7FFF,
        round((where.heading_deg % 360.0) * 10) % 3600,
    )
    return basic + common + pv + b"\x00" * 4 + payload


def ethernet_frame(
    cpm: bytes, station_id: int, station_type: int, t_ns: int, where: GeoPosition
) -> bytes:
    """An Ethernet frame carrying ``cpm`` over GeoNetworking SHB and BTP-B (port 2009)."""
    gn = _geonet(btp_b(cpm), station_id, station_type, t_ns, where)
    return _BROADCAST + station_address(station_id) + struct.pack(">H", ETHERTYPE_GEONET) + gn


def write_pcap(
    stream: BinaryIO,
    frames: Iterable[tuple[int, bytes]],
) -> int:
    """Write ``(t_ns, Ethernet frame)`` pairs as a pcap file, each as it comes; returns
    the frames written."""
    writer = PcapWriter(stream, linktype=LINKTYPE_ETHERNET)
    n = 0
    for t_ns, frame in frames:
        writer.write(t_ns, frame)
        n += 1
    return n


def _from_geonet(packet: bytes, where: str) -> bytes:
    """The CPM inside a GeoNetworking packet (basic header first)."""
    if len(packet) < _BASIC_LEN + _COMMON_LEN:
        raise CpmFormatError(f"{where}: GeoNetworking packet of {len(packet)} bytes is truncated")
    version, nh = packet[0] >> 4, packet[0] & 0x0F
    if version != GN_VERSION or nh != _NH_COMMON:
        raise CpmFormatError(
            f"{where}: GeoNetworking version {version} / next header {nh}: only a "
            "version-1 unsecured packet (next header 1) is read"
        )
    common = packet[_BASIC_LEN : _BASIC_LEN + _COMMON_LEN]
    next_header, ht, hst = common[0] >> 4, common[1] >> 4, common[1] & 0x0F
    (length,) = struct.unpack(">H", common[4:6])
    if next_header != _NH_BTP_B:
        raise CpmFormatError(f"{where}: GeoNetworking next header {next_header} is not BTP-B")
    ext = _EXTENDED_LEN.get((ht, hst))
    if ext is None:
        raise CpmFormatError(f"{where}: GeoNetworking header type {ht}/{hst} is not read")
    body = packet[_BASIC_LEN + _COMMON_LEN + ext :]
    if len(body) < length:
        raise CpmFormatError(
            f"{where}: GeoNetworking payload of {len(body)} bytes, header says {length}"
        )
    return _from_btp(body[:length], where)


def _from_btp(packet: bytes, where: str) -> bytes:
    if len(packet) < _BTP_LEN:
        raise CpmFormatError(f"{where}: BTP-B header truncated")
    port, _ = struct.unpack(">HH", packet[:_BTP_LEN])
    if port != BTP_CPM_PORT:
        raise CpmFormatError(f"{where}: BTP-B destination port {port} is not the CPM's (2009)")
    return packet[_BTP_LEN:]


def split_datagram(data: bytes, where: str = "datagram") -> bytes:
    """The CPM in a UDP datagram: a bare CPM, BTP-B + CPM, or GeoNetworking + BTP-B + CPM.

    A bare CPM v2 starts with 0x02 0x0E (protocol version 2, message id 14); a
    BTP-B header for the CPM with 0x07 0xD9 (port 2009); a GeoNetworking packet
    with 0x11 (version 1, common header next).

    Raises:
        CpmFormatError: none of the three.
    """
    if len(data) >= 2 and data[0] == 0x07 and data[1] == 0xD9:
        return _from_btp(data, where)
    if len(data) >= 1 and data[0] == (GN_VERSION << 4) | _NH_COMMON:
        return _from_geonet(data, where)
    return data


def read_pcap_cpms(data: bytes, name: str) -> tuple[list[tuple[int, int, bytes]], list[str]]:
    """The CPMs of a capture of Ethernet frames: ``(frame number, t_ns, CPM bytes)``.

    Frames that are not GeoNetworking are passed over; GeoNetworking frames that
    carry no readable CPM are named in the second list (frame number and reason).

    Raises:
        CaptureFormatError: the data is not a pcap or pcapng capture.
    """
    out: list[tuple[int, int, bytes]] = []
    problems: list[str] = []
    for chunk in iter_chunks(data, name):
        for i in range(len(chunk)):
            frame_no = int(chunk.frame_no[i])
            start, caplen = int(chunk.start[i]), int(chunk.caplen[i])
            frame = chunk.buf[start : start + caplen]
            if int(chunk.linktype[i]) != LINKTYPE_ETHERNET or len(frame) < 14:
                continue
            if struct.unpack(">H", frame[12:14])[0] != ETHERTYPE_GEONET:
                continue
            try:
                cpm = _from_geonet(frame[14:], f"{name}: frame {frame_no}")
            except CpmFormatError as err:
                problems.append(str(err))
                continue
            out.append((frame_no, int(chunk.t_ns[i]), cpm))
        problems.extend(p.error(name).args[0] for p in chunk.problems)
    return out, problems


PCAP_MAGICS = (b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\xc3\xd4", b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d")
PCAPNG_MAGIC = b"\x0a\x0d\x0d\x0a"


@dataclass(frozen=True, slots=True)
class CpmFile:
    """The CPMs found in a file."""

    cpms: list[tuple[int, int, bytes]]
    """``(frame number, t_ns, CPM bytes)``; a one-message file is frame 1 at time 0."""
    problems: list[str]
    """Frames of a capture that carry no readable CPM, with the reason."""
    capture: bool
    """Whether the file is a pcap/pcapng capture (else one message)."""


def read_cpm_file(path: str | Path) -> CpmFile:
    """The CPMs of a file: a pcap/pcapng of Ethernet frames (as :func:`read_pcap_cpms`),
    or one message (a bare CPM, or behind BTP-B or GeoNetworking headers).

    Raises:
        DataFormatError: the file cannot be read.
        CpmFormatError: a one-message file whose headers are not a CPM's.
        CaptureFormatError: a capture that cannot be parsed.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as err:
        raise DataFormatError(f"{p}: cannot read: {err.strerror or err}") from err
    if data[:4] in PCAP_MAGICS or data[:4] == PCAPNG_MAGIC:
        found, problems = read_pcap_cpms(data, str(p))
        return CpmFile(found, problems, capture=True)
    return CpmFile([(1, 0, split_datagram(data, str(p)))], [], capture=False)
