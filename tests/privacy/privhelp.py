"""Helpers for privacy tests: known MACs, their frames, a capture file of them, and a
socket that notes when datagrams arrive."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from rfsas_hw.records import FrameKind, ObservationBatch
from rfsas_hw.twin.capture_writer import write_capture
from rfsas_hw.twin.frames import RadiotapInfo, dot11_frame, radiotap_header, with_fcs

REPO = Path(__file__).resolve().parents[2]
CALIBRATION = REPO / "calibration" / "example_cal.yaml"

KNOWN_MACS = [
    0x3C22FB0102AB,
    0xA4C3F0123456,
    0x02DEADBEEF01,
    0xF0F1F2F3F4F5,
    0x001122334455,
    0x7EA1B2C3D4E5,
]


def known_frames(t0_ns: int) -> ObservationBatch:
    rng = np.random.default_rng(11)
    n = 600
    which = rng.integers(0, len(KNOWN_MACS), n)
    macs = np.array(KNOWN_MACS, np.uint64)[which]
    # each transmitter at its own steady level (as from one place), within 3 dB
    rssi1 = rng.uniform(-65, -40, len(KNOWN_MACS))[which] + rng.uniform(0, 3, n)
    return ObservationBatch(
        t_ns=t0_ns + np.sort(rng.integers(0, 50_000_000, n)),
        mac=macs,
        freq_mhz=np.full(n, 2437),
        channel=np.full(n, 6),
        rssi_dbm=np.stack([rssi1, rssi1 + rng.uniform(-4, 4, n)], axis=1),
        seq=rng.integers(0, 4096, n).astype(np.int32),
    )


def write_known_capture(path: Path, t0_ns: int) -> int:
    """A radiotap pcap of probe requests and data frames from the known MACs, heard on
    two chains, captured from ``t0_ns`` on; returns the frame count."""
    frames = known_frames(t0_ns)

    def records() -> Iterator[tuple[int, bytes]]:
        for i, obs in enumerate(frames):
            kind = FrameKind.QOS_DATA if i % 3 == 0 else FrameKind.PROBE_REQUEST
            r1, r2 = (round(v) for v in obs.rssi_dbm)
            info = RadiotapInfo(
                tsft_us=obs.t_ns // 1000,
                freq_mhz=2437,
                rate_500kbps=2,
                combined_dbm=max(r1, r2),
                chains=[(r1, 0), (r2, 1)],
            )
            frame = dot11_frame(kind, obs.mac, obs.seq or 0, 6, obs.t_ns, peer=0x0A0B0C0D0E0F)
            yield obs.t_ns, radiotap_header(info) + with_fcs(frame)

    return write_capture(path, records(), "pcap")


class ArrivalStamps:
    """A loopback UDP socket that notes each datagram's arrival time (UTC ns).

    A receiver fed these times judges freshness by when a message arrived, not by
    when a loaded test machine got round to checking it (messages are ``stale``
    after one second).
    """

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.3)
        self.url = f"udp://127.0.0.1:{self.sock.getsockname()[1]}"
        self.datagrams: list[tuple[bytes, int]] = []

    def collect_while(self, running: Callable[[], bool], limit_s: float = 120.0) -> None:
        """Receive until ``running()`` is false and nothing arrived for 0.3 s, or
        ``limit_s`` seconds have passed."""
        deadline = time.monotonic() + limit_s
        while time.monotonic() < deadline:
            try:
                datagram = self.sock.recv(65536)
            except TimeoutError:
                if not running():
                    return
                continue
            self.datagrams.append((datagram, time.time_ns()))

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> ArrivalStamps:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


STILL = ["--prove-motion", "0"]
"""Options for replaying a capture whose transmitters stand still (as these helpers'
do): on a fixed mount the motion rule refuses every bearing of a transmitter that never
moves, and the tests that replay one check something else."""
