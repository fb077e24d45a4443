"""Nonce epochs: fixed time slots numbered from the Unix epoch, with a grace period.

Epoch ``k`` covers UTC times ``[k·epoch_s, (k+1)·epoch_s)``. Every sensor of a
deployment numbers epochs the same way, so the same MAC heard by two sensors
in the same epoch hashes to the same emitter id.

Senders hash with the epoch their frame was captured in. Receivers are more
lenient at the boundary: for ``grace_s`` seconds after an epoch starts they
still accept (and keep the nonce of) the previous epoch, because a message
generated just before the boundary arrives just after it; and for ``grace_s``
seconds before the boundary they already accept the next epoch, so a sender
whose clock runs slightly ahead is not cut off. Outside that window an old
nonce is forgotten, which bounds how long a stolen receiver can link ids.
"""

from __future__ import annotations

from dataclasses import dataclass

NS_PER_S = 1_000_000_000
DEFAULT_EPOCH_S = 60.0
DEFAULT_GRACE_S = 5.0


@dataclass(frozen=True, slots=True)
class EpochSchedule:
    """How a deployment slices time into nonce epochs.

    Args:
        epoch_s: epoch length, seconds (≥ 1; every sensor and receiver must agree).
        grace_s: receiving-side grace period at each boundary, seconds
            (0 ≤ grace_s < epoch_s / 2).

    Raises:
        ValueError: on an epoch length below 1 s or a grace period outside its range.
    """

    epoch_s: float = DEFAULT_EPOCH_S
    grace_s: float = DEFAULT_GRACE_S

    def __post_init__(self) -> None:
        if not self.epoch_s >= 1.0:
            raise ValueError(f"epoch length must be at least 1 s, got {self.epoch_s} s")
        if not 0.0 <= self.grace_s < self.epoch_s / 2:
            raise ValueError(
                f"grace period must be in [0, epoch_s/2) = [0, {self.epoch_s / 2:g}) s, "
                f"got {self.grace_s} s"
            )

    @property
    def epoch_ns(self) -> int:
        """Epoch length, nanoseconds."""
        return int(self.epoch_s * NS_PER_S)

    @property
    def grace_ns(self) -> int:
        """Grace period, nanoseconds."""
        return int(self.grace_s * NS_PER_S)

    def epoch_of(self, t_ns: int) -> int:
        """Epoch number of a UTC time in nanoseconds."""
        return int(t_ns) // self.epoch_ns

    def start_ns(self, epoch: int) -> int:
        """UTC time (ns) at which ``epoch`` begins."""
        return int(epoch) * self.epoch_ns

    def accepted_epochs(self, now_ns: int) -> tuple[int, ...]:
        """Epochs a receiver accepts at ``now_ns``: the current one, plus a neighbour near a
        boundary (the previous one just after it, the next one just before it)."""
        current = self.epoch_of(now_ns)
        into = int(now_ns) - self.start_ns(current)
        epochs = [current]
        if into < self.grace_ns:
            epochs.insert(0, current - 1)
        if self.epoch_ns - into <= self.grace_ns:
            epochs.append(current + 1)
        return tuple(epochs)

    def accepts(self, epoch: int, now_ns: int) -> bool:
        """True when a receiver at ``now_ns`` accepts messages and nonces of ``epoch``."""
        return int(epoch) in self.accepted_epochs(now_ns)

    def expired(self, epoch: int, now_ns: int) -> bool:
        """True once ``epoch`` and its grace period are over at ``now_ns``: its nonce can go."""
        return int(now_ns) >= self.start_ns(int(epoch) + 1) + self.grace_ns


def epoch_of(t_ns: int, epoch_s: float = DEFAULT_EPOCH_S) -> int:
    """Epoch number of a UTC time: fixed slots of ``epoch_s`` seconds since the Unix epoch."""
    return int(t_ns) // int(epoch_s * NS_PER_S)
