"""Frame → advisory latency: each advisory that carried a fresh fix, matched with its arrival.

A backend reports, after judging, which of its advisories (backend id, sequence number)
carried a fix made in that step, the time of that fix's newest frame and the time the
step began; the vehicles' receivers report each advisory they verified with its arrival
time and the time its backend signed it. The two reports
come over different pipes and either may come first: an advisory published early in a
long judging pass can reach its vehicle before its backend has reported. :class:`LatencyMatch`
keeps each side until the other comes (bounded in time and in size) and gives the latency
at whichever comes second, so no sample depends on that order, split into the three
parts of its path (:class:`LatencyParts`).
"""

from __future__ import annotations

from collections import deque
from typing import NamedTuple

NS_PER_S = 1_000_000_000
ARRIVED_MEMORY_S = 5.0
"""An arrival no report has matched is forgotten this long after it arrived (an advisory
that carried no fix of its step is never reported), seconds of the deployment's clock."""
FRAMES_KEPT = 200_000
"""At most this many reported advisories wait for their arrival (an advisory whose vehicle
left never arrives); beyond it the oldest half is forgotten."""

Key = tuple[str, int]
"""An advisory: (backend id, sequence number)."""

__all__ = ["ARRIVED_MEMORY_S", "FRAMES_KEPT", "Key", "LatencyMatch", "LatencyParts"]


class LatencyParts(NamedTuple):
    """Where one advisory's frame → advisory latency went, seconds of the deployment's
    clock. The parts add up to the whole (:attr:`total_s`)."""

    to_step_s: float
    """The fix's newest frame → the start of the backend step that made the fix: the
    sensor's slot, its publishing, the broker to the backend and the backend's wait for
    the step. A twin worker behind its clock, or a simulator behind its lead, shows here."""
    judging_s: float
    """That step's start → the advisory signed: the step itself, and judging and signing
    the cars advised before this one."""
    delivery_s: float
    """Signed → verified at its vehicle: the broker and the vehicle's receiver."""

    @property
    def total_s(self) -> float:
        """Frame → advisory, seconds."""
        return self.to_step_s + self.judging_s + self.delivery_s


class LatencyMatch:
    """Matches backends' reports with vehicles' arrivals (see the module docstring)."""

    def __init__(self) -> None:
        self._reported_ns: dict[Key, tuple[int, int]] = {}
        """Reported and not arrived: the newest frame of the fix each carried and the start
        of the step that made it, UTC ns."""
        self._arrived_ns: dict[Key, tuple[int, int]] = {}
        """Arrived and not reported: each one's arrival and signing, UTC ns."""
        self._order: deque[tuple[int, Key]] = deque()
        """The arrivals waiting in :attr:`_arrived_ns`, oldest first."""

    def sent(self, key: Key, frame_ns: int, step_ns: int) -> LatencyParts | None:
        """Advisory ``key`` carried a fix whose newest frame was at ``frame_ns``, made by
        the step that began at ``step_ns`` (UTC ns): its latency if it has arrived
        already, else None (given on arrival)."""
        arrived = self._arrived_ns.pop(key, None)
        if arrived is not None:
            return _parts(frame_ns, step_ns, *arrived)
        self._reported_ns[key] = (frame_ns, step_ns)
        if len(self._reported_ns) > FRAMES_KEPT:
            for old in list(self._reported_ns)[: FRAMES_KEPT // 2]:
                del self._reported_ns[old]
        return None

    def arrived(self, key: Key, t_ns: int, signed_ns: int) -> LatencyParts | None:
        """Advisory ``key``, signed at ``signed_ns``, was verified at its vehicle at
        ``t_ns`` (UTC ns): its latency if its backend reported a fix in it already, else
        None (given on the report, if one comes within :data:`ARRIVED_MEMORY_S`)."""
        reported = self._reported_ns.pop(key, None)
        if reported is not None:
            return _parts(*reported, t_ns, signed_ns)
        self._arrived_ns[key] = (t_ns, signed_ns)
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
        return len(self._reported_ns) + len(self._arrived_ns)


def _parts(frame_ns: int, step_ns: int, t_ns: int, signed_ns: int) -> LatencyParts:
    return LatencyParts(
        (step_ns - frame_ns) / NS_PER_S,
        (signed_ns - step_ns) / NS_PER_S,
        (t_ns - signed_ns) / NS_PER_S,
    )
