"""802.11 frames and radiotap headers as a mac80211 driver would hand them to a capture.

The radiotap layout follows Linux mac80211 (``ieee80211_add_rx_radiotap_header``):
namespace 0 carries TSFT, Flags, Rate, Channel, the combined dBm signal and
RX flags; then one extra radiotap namespace per receive chain with
``dBm antenna signal`` and ``antenna`` (the pair written as signal, index).
Every field is aligned to its natural size, measured from the start of the
radiotap header. Frames carry their FCS (Flags bit 0x10).

Frame bodies are deterministic functions of the transmission (MAC, sequence
number, time), so two sensors that hear the same frame capture the same bytes.
"""

from __future__ import annotations

import hashlib
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

from rfsas_hw.records import FrameKind

# radiotap bits used here
TSFT, FLAGS, RATE, CHANNEL, DBM_ANTSIGNAL, ANTENNA, RX_FLAGS = 0, 1, 2, 3, 5, 11, 14
NS_RADIOTAP, EXT = 29, 31
FLAG_FCS = 0x10
CHAN_CCK, CHAN_OFDM, CHAN_2GHZ, CHAN_5GHZ = 0x0020, 0x0040, 0x0080, 0x0100
_FIELD = {  # bit: (alignment, struct format)
    TSFT: (8, "<Q"),
    FLAGS: (1, "<B"),
    RATE: (1, "<B"),
    CHANNEL: (2, "<HH"),
    DBM_ANTSIGNAL: (1, "<b"),
    ANTENNA: (1, "<B"),
    RX_FLAGS: (2, "<H"),
}
BROADCAST = b"\xff" * 6
RATES_IE = bytes([1, 8, 0x82, 0x84, 0x8B, 0x96, 0x0C, 0x12, 0x18, 0x24])
EXT_RATES_IE = bytes([50, 4, 0x30, 0x48, 0x60, 0x6C])


@dataclass(frozen=True)
class RadiotapInfo:
    """What the driver reports about one received frame."""

    tsft_us: int
    """The card's TSF timer at the first bit of the frame, microseconds."""
    freq_mhz: int
    """Channel centre frequency, MHz."""
    rate_500kbps: int
    """Data rate in 500 kb/s units."""
    combined_dbm: int | None
    """Combined signal, dBm (None: not reported)."""
    chains: Sequence[tuple[int, int]]
    """(signal dBm, antenna index) of every reported chain, in chain order."""


def _pack_fields(fields: Sequence[tuple[int, tuple[int, ...]]], start: int) -> tuple[bytes, int]:
    out = bytearray()
    offset = start
    for bit, values in fields:
        align, fmt = _FIELD[bit]
        pad = (-offset) % align
        out += b"\x00" * pad
        data = struct.pack(fmt, *values)
        out += data
        offset += pad + len(data)
    return bytes(out), offset


def radiotap_header(info: RadiotapInfo) -> bytes:
    """A mac80211-style radiotap header with one namespace per chain."""
    cck = info.rate_500kbps in (2, 4, 11, 22)
    band = CHAN_2GHZ if info.freq_mhz < 3000 else CHAN_5GHZ
    chan_flags = band | (CHAN_CCK if cck else CHAN_OFDM)
    ns0: list[tuple[int, tuple[int, ...]]] = [
        (TSFT, (info.tsft_us,)),
        (FLAGS, (FLAG_FCS,)),
        (RATE, (info.rate_500kbps,)),
        (CHANNEL, (info.freq_mhz, chan_flags)),
    ]
    if info.combined_dbm is not None:
        ns0.append((DBM_ANTSIGNAL, (info.combined_dbm,)))
    ns0.append((RX_FLAGS, (0,)))
    words = [sum(1 << bit for bit, _ in ns0)]
    for _ in info.chains:
        words[-1] |= (1 << EXT) | (1 << NS_RADIOTAP)
        words.append((1 << DBM_ANTSIGNAL) | (1 << ANTENNA))
    start = 4 + 4 * len(words)
    data, end = _pack_fields(ns0, start)
    chain_data = b"".join(struct.pack("<bB", sig, idx) for sig, idx in info.chains)
    length = end + len(chain_data)
    head = struct.pack("<BBH", 0, 0, length) + b"".join(struct.pack("<I", w) for w in words)
    return head + data + chain_data


def _mac_bytes(mac: int) -> bytes:
    return int(mac).to_bytes(6, "big")


def _seq_ctl(seq: int) -> bytes:
    return struct.pack("<H", (max(seq, 0) & 0xFFF) << 4)


def _filler(mac: int, t_ns: int, n: int) -> bytes:
    out = b""
    counter = 0
    while len(out) < n:
        key = f"{mac:012x}:{t_ns}:{counter}".encode()
        out += hashlib.blake2b(key, digest_size=64).digest()
        counter += 1
    return out[:n]


def dot11_frame(
    kind: int,
    mac: int,
    seq: int,
    channel: int,
    t_ns: int,
    *,
    peer: int = 0,
    ssid: str = "",
    beacon_tsf_us: int = 0,
) -> bytes:
    """An 802.11 frame (without FCS) of ``kind`` sent by ``mac``.

    Beacons carry ``ssid`` and ``beacon_tsf_us``; QoS data goes to ``peer``
    with the Protected bit and a CCMP header, its payload derived from the
    MAC and time. Other kinds are sent as probe requests.
    """
    sc = _seq_ctl(seq)
    ds = bytes([3, 1, channel & 0xFF])
    if kind == FrameKind.BEACON:
        name = ssid.encode("utf-8")[:32]
        body = struct.pack("<QHH", beacon_tsf_us, 100, 0x0421)
        body += bytes([0, len(name)]) + name + RATES_IE + ds + EXT_RATES_IE
        return b"\x80\x00\x00\x00" + BROADCAST + _mac_bytes(mac) * 2 + sc + body
    if kind in (FrameKind.QOS_DATA, FrameKind.DATA):
        pn = (t_ns // 1000) & 0xFFFF_FFFF_FFFF
        ccmp = struct.pack("<HBB", pn & 0xFFFF, 0, 0x20) + struct.pack("<I", pn >> 16)
        payload = _filler(mac, t_ns, 96)
        head = b"\x88\x41\x2c\x00" + _mac_bytes(peer) + _mac_bytes(mac) + _mac_bytes(peer)
        return head + sc + b"\x00\x00" + ccmp + payload
    body = bytes([0, 0]) + RATES_IE + EXT_RATES_IE + ds
    return b"\x40\x00\x00\x00" + BROADCAST + _mac_bytes(mac) + BROADCAST + sc + body


def with_fcs(frame: bytes) -> bytes:
    """The frame followed by its 802.11 FCS (CRC-32, little-endian)."""
    return frame + struct.pack("<I", zlib.crc32(frame) & 0xFFFF_FFFF)


def rate_for(kind: int, freq_mhz: int) -> int:
    """Data rate of a frame in 500 kb/s units: 1 Mb/s management at 2.4 GHz, OFDM otherwise."""
    if freq_mhz >= 3000:
        return 12 if kind != FrameKind.QOS_DATA else 48
    return 2 if kind != FrameKind.QOS_DATA else 48
