"""Replay protection: each (sender, sequence number) is accepted once within the time window.

A receiver already drops messages older than its ``max_age_s``; a replay can
therefore only succeed inside that window, and that is the window kept here:
per sender, the sequence numbers accepted with generation times inside it.
A duplicate sequence number is a replay. Memory is bounded: when a sender's
table is full the oldest entry is dropped and nothing generated at or before
it is accepted any more (a floor), so eviction never reopens a hole.

A sender that restarts may start its sequence numbers anywhere; only an exact
repeat inside the window is refused, which is why publishers start at a random
sequence number.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field


@dataclass(slots=True)
class _SenderWindow:
    seen: dict[int, int] = field(default_factory=dict)
    """seq → generation time (µs)."""
    heap: list[tuple[int, int]] = field(default_factory=list)
    """(generation time µs, seq), oldest first, for pruning."""
    floor_us: int = -1
    """Nothing generated at or before this time is accepted."""


class ReplayGuard:
    """Per-sender duplicate detection over a sliding time window.

    Args:
        window_us: how long a sequence number is remembered, µs (the receiver's
            maximum message age plus its future-skew allowance).
        capacity: most sequence numbers remembered per sender.

    Raises:
        ValueError: on a non-positive window or capacity.
    """

    def __init__(self, window_us: int, capacity: int = 4096) -> None:
        if window_us <= 0 or capacity <= 0:
            raise ValueError("replay window and capacity must be positive")
        self.window_us = int(window_us)
        self.capacity = int(capacity)
        self._senders: dict[str, _SenderWindow] = {}

    def check_and_record(self, sender_id: str, seq: int, t_gen_us: int, now_us: int) -> bool:
        """Accept (and remember) the message, or return False if it is a replay."""
        win = self._senders.get(sender_id)
        if win is None:
            win = self._senders[sender_id] = _SenderWindow()
        win.floor_us = max(win.floor_us, now_us - self.window_us)
        self._prune(win)
        if t_gen_us <= win.floor_us or seq in win.seen:
            return False
        win.seen[seq] = t_gen_us
        heapq.heappush(win.heap, (t_gen_us, seq))
        while len(win.seen) > self.capacity:
            evicted_us, evicted_seq = heapq.heappop(win.heap)
            del win.seen[evicted_seq]
            win.floor_us = max(win.floor_us, evicted_us)
        return True

    def seen(self, sender_id: str, seq: int, t_gen_us: int) -> bool:
        """True when a message with this sequence number and generation time was
        accepted and is still remembered (nothing is recorded). Only verified
        messages are recorded, so a receiver may drop such a copy before checking
        its signature: it is either a replay or a forgery."""
        win = self._senders.get(sender_id)
        return win is not None and win.seen.get(seq) == t_gen_us

    @staticmethod
    def _prune(win: _SenderWindow) -> None:
        heap = win.heap
        while heap and heap[0][0] <= win.floor_us:
            _, seq = heapq.heappop(heap)
            del win.seen[seq]

    def remembered(self, sender_id: str) -> int:
        """How many sequence numbers are remembered for ``sender_id``."""
        win = self._senders.get(sender_id)
        return 0 if win is None else len(win.seen)

    def forget(self, sender_id: str) -> None:
        """Drop everything remembered about ``sender_id``."""
        self._senders.pop(sender_id, None)
