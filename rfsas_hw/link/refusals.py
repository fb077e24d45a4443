"""Refusal watch: a per-sender alarm when every message of a sender is refused.

The latency watch follows senders once they are verified; a sender whose
messages are *all* refused never gets there, and its loss is silent: a clock
0.3 s ahead (``future``), 1.5 s behind (``stale``), a nonce that differs from
the receiver's (``bad_preauth``, ``no_preauth_key``, ``wrong_epoch``), a card
that is not enrolled (``unknown_sender``). The refusal watch counts, per
claimed sender id, the refusals for those reasons since the sender's last
verified message; at ``run`` of them in a row it raises an alarm, logged once
at WARNING with the cause named:

- ``clock skew`` (``future``): the sender's clock runs ahead, with its offset
  measured as the median of (generation time − receive time) over the run;
- ``late`` (``stale``): the messages arrive older than the age limit, with the
  same median. A clock that runs behind and a sender that publishes late (an
  overloaded sensor, a backlog in the network path) look the same from here, so
  the alarm names both;
- ``nonce mismatch`` (``bad_preauth``/``no_preauth_key``/``wrong_epoch``): the
  sender tags with another epoch nonce than this receiver holds (an authority
  restarted without its state, a party not enrolled with the authority) — or
  someone forges messages under its id;
- ``unenrolled`` (``unknown_sender``): no card of that id in the trust
  directory.

The next verified message of the sender clears the alarm (logged at INFO).
Sender ids are claimed, not proven, so the watch keeps at most ``max_senders``
of them (the least recently refused go first) and logs at most
``max_alarm_logs`` new alarms per minute (the others are still counted).
"""

from __future__ import annotations

import logging
import statistics
import time
from collections import Counter, OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

log = logging.getLogger(__name__)

CAUSES = {
    "future": "clock skew",
    "stale": "late",
    "bad_preauth": "nonce mismatch",
    "no_preauth_key": "nonce mismatch",
    "wrong_epoch": "nonce mismatch",
    "unknown_sender": "unenrolled",
}
"""Reasons the watch follows, and the cause each one points to."""

_ADVICE = {
    "clock skew": "check the sender's time sync (NTP/PTP)",
    "late": "check the sender's time sync (NTP/PTP) and whether it keeps up (its load, its uplink)",
    "nonce mismatch": (
        "check that the sender and this receiver take their nonces from the same "
        "authority (restarted without its nonces.state?), or someone forges its id"
    ),
    "unenrolled": "enroll its card (rfsas keys enroll) or check its id",
}


@dataclass(frozen=True, slots=True)
class RefusalConfig:
    """Thresholds of the refusal watch.

    Raises:
        ValueError: a run, sender cap or log budget below 1.
    """

    run: int = 20
    """Refusals in a row (no verified message between) that raise the alarm."""
    max_senders: int = 1024
    """Claimed sender ids followed at once."""
    max_alarm_logs: int = 20
    """New alarms logged per minute, at most."""
    offsets: int = 64
    """Clock offsets kept per sender for the median."""

    def __post_init__(self) -> None:
        if min(self.run, self.max_senders, self.max_alarm_logs, self.offsets) < 1:
            raise ValueError("run, max_senders, max_alarm_logs and offsets must be >= 1")


@dataclass(frozen=True, slots=True)
class RefusalAlarm:
    """A sender all of whose recent messages were refused."""

    sender_id: str
    """The sender id the refused messages claim."""
    cause: str
    """``clock skew``, ``late``, ``nonce mismatch`` or ``unenrolled``."""
    reasons: dict[str, int]
    """Refusals of the run by reason."""
    offset_s: float | None
    """Median generation − receive time of the run, seconds (``clock skew`` and
    ``late`` only; positive: the sender's clock runs ahead)."""

    @property
    def refused(self) -> int:
        """Refusals in the run."""
        return sum(self.reasons.values())

    def describe(self) -> str:
        """One line for the log and the operator."""
        reasons = ", ".join(f"{k} {v}" for k, v in sorted(self.reasons.items()))
        text = f"link from {self.sender_id}: {self.refused} messages in a row refused ({reasons})"
        text += f": {self.cause}"
        if self.offset_s is not None and self.cause == "late":
            text += (
                f", they arrive {-self.offset_s * 1e3:.0f} ms after their generation time"
                " (its clock runs behind this receiver's, or it sends late)"
            )
        elif self.offset_s is not None:
            way = "ahead of" if self.offset_s > 0 else "behind"
            text += f", its clock runs {abs(self.offset_s) * 1e3:.0f} ms {way} this receiver's"
        return f"{text}; {_ADVICE[self.cause]}"


@dataclass(slots=True)
class _Run:
    n: int = 0
    reasons: Counter[str] = field(default_factory=Counter)
    offsets: list[float] = field(default_factory=list)
    alarm: RefusalAlarm | None = None


class RefusalWatch:
    """Counts refusals per claimed sender and raises alarms (see the module docstring).

    Args:
        config: thresholds.
        clock: monotonic seconds, for the alarm log budget.
    """

    def __init__(
        self, config: RefusalConfig | None = None, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.config = config or RefusalConfig()
        self.clock = clock
        self.alarms_raised = 0
        """Alarms raised so far (logged or not)."""
        self._runs: OrderedDict[str, _Run] = OrderedDict()
        self._logged: list[float] = []

    def refused(self, sender_id: str, reason: str, offset_s: float | None = None) -> None:
        """Count a refusal of a message claiming ``sender_id`` (reasons outside
        :data:`CAUSES` are ignored); ``offset_s``: its generation − receive time."""
        cause = CAUSES.get(reason)
        if cause is None or not sender_id:
            return
        run = self._runs.get(sender_id)
        if run is None:
            if len(self._runs) >= self.config.max_senders:
                self._runs.popitem(last=False)
            run = self._runs[sender_id] = _Run()
        elif run.n % 64 == 0:  # recency matters for eviction only: refreshed now and then
            self._runs.move_to_end(sender_id)
        run.reasons[reason] += 1
        run.n += 1
        if offset_s is not None:
            run.offsets.append(offset_s)
            if len(run.offsets) > self.config.offsets:
                del run.offsets[0]
        if run.alarm is None and run.n >= self.config.run:
            run.alarm = self._alarm(sender_id, run)
            self.alarms_raised += 1
            if self._may_log():
                log.warning("%s", run.alarm.describe())

    def verified(self, sender_id: str) -> None:
        """A message of ``sender_id`` was verified: its run ends (an alarm clears)."""
        run = self._runs.pop(sender_id, None)
        if run is not None and run.alarm is not None:
            log.info("link from %s: verified again after %d refusals", sender_id, run.n)

    @property
    def alarms(self) -> dict[str, RefusalAlarm]:
        """Senders in alarm now, with what the run looks like now."""
        return {s: self._alarm(s, r) for s, r in self._runs.items() if r.alarm is not None}

    def _alarm(self, sender_id: str, run: _Run) -> RefusalAlarm:
        reason = run.reasons.most_common(1)[0][0]
        cause = CAUSES[reason]
        timed = cause in ("clock skew", "late") and run.offsets
        offset = statistics.median(run.offsets) if timed else None
        return RefusalAlarm(sender_id, cause, dict(run.reasons), offset)

    def _may_log(self) -> bool:
        now = self.clock()
        self._logged = [t for t in self._logged if now - t < 60.0]
        if len(self._logged) >= self.config.max_alarm_logs:
            return False
        self._logged.append(now)
        return True
