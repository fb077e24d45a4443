"""Frame → advisory latency: each advisory that carried a fresh fix, matched with its arrival.

A backend reports, after judging, which of its advisories (backend id, sequence number)
carried a fix made in that step and the time of that fix's newest frame; the vehicles'
receivers report each advisory they verified with its arrival time. The two reports
come over different pipes and either may come first: an advisory published early in a
long judging pass can reach its vehicle before its backend has reported. :class:`LatencyMatch`
keeps each side until the other comes (bounded in time and in size) and gives the latency
at whichever comes second, so no sample depends on that order.
"""

from __future__ import annotations

from collections import deque

NS_PER_S = 1_000_000_000
ARRIVED_MEMORY_S = 5.0
"""An arrival no report has matched is forgotten this long after it arrived (an advisory
that carried no fix of its step is never reported), seconds of the deployment's clock."""
FRAMES_KEPT = 200_000
"""At most this many reported advisories wait for their arrival (an advisory whose vehicle
left never arrives); beyond it the oldest half is forgotten."""

Key = tuple[str, int]
"""An advisory: (backend id, sequence number)."""

__all__ = ["ARRIVED_MEMORY_S", "FRAMES_KEPT", "Key", "LatencyMatch"]


class LatencyMatch:
    """Matches backends' reports with vehicles' arrivals (see the module docstring)."""

    def __init__(self) -> None:
        self._frame_ns: dict[Key, int] = {}
        """Reported and not arrived: the newest frame of the fix each carried, UTC ns."""
        self._arrived_ns: dict[Key, int] = {}
        """Arrived and not reported: each one's arrival, UTC ns."""
        self._order: deque[tuple[int, Key]] = deque()
        """The arrivals waiting in :attr:`_arrived_ns`, oldest first."""

    def sent(self, key: Key, frame_ns: int) -> float | None:
        """Advisory ``key`` carried a fix whose newest frame was at ``frame_ns`` (UTC ns):
        its latency in seconds if it has arrived already, else None (given on arrival)."""
        arrived = self._arrived_ns.pop(key, None)
        if arrived is not None:
            return (arrived - frame_ns) / NS_PER_S
        self._frame_ns[key] = frame_ns
        if len(self._frame_ns) > FRAMES_KEPT:
            for old in list(self._frame_ns)[: FRAMES_KEPT // 2]:
                del self._frame_ns[old]
        return None

    def arrived(self, key: Key, t_ns: int) -> float | None:
        """Advisory ``key`` was verified at its vehicle at ``t_ns`` (UTC ns): its latency in
        seconds if its backend reported a fix in it already, else None (given on the report,
        if one comes within :data:`ARRIVED_MEMORY_S`)."""
        frame_ns = self._frame_ns.pop(key, None)
        if frame_ns is not None:
            return (t_ns - frame_ns) / NS_PER_S
        self._arrived_ns[key] = t_ns
        self._order.append((t_ns, key))
        return None

    def forget(self, now_ns: int) -> None:
        """Forget the arrivals older than :data:`ARRIVED_MEMORY_S` at ``now_ns`` (UTC ns)."""
        old = now_ns - round(ARRIVED_MEMORY_S * NS_PER_S)
        order = self._order
        while order and order[0][0] < old:
            self._arrived_ns.pop(order.popleft()[1], None)

    def __len__(self) -> int:
        """Advisories waiting for their other half."""
        return len(self._frame_ns) + len(self._arrived_ns)
