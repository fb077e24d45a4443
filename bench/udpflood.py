"""A paced UDP flood to a local port, for the receivers' overload benchmarks."""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Sequence


def send_paced(payloads: Sequence[bytes], port: int, rate: int, seconds: float) -> int:
    """Send ``rate × seconds`` datagrams to ``127.0.0.1:port`` at ``rate`` per second,
    cycling through ``payloads``; the rate achieved, datagrams per second (a full socket
    buffer drops a datagram silently: that is the point of a flood)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    total = int(rate * seconds)
    sent = 0
    t0 = time.perf_counter()
    try:
        while sent < total:
            due = min(total, int((time.perf_counter() - t0) * rate))
            if due <= sent:
                time.sleep(0.0005)
                continue
            for _ in range(due - sent):
                with contextlib.suppress(OSError):
                    sock.sendto(payloads[sent % len(payloads)], ("127.0.0.1", port))
                sent += 1
        return round(sent / (time.perf_counter() - t0))
    finally:
        sock.close()
