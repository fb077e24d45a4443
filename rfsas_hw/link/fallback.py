"""Out-of-band fallback: a primary and a secondary path, switched by the latency watch.

Denial of service on the link (jamming, congestion, a flood) shows up as
messages that arrive late or not at all (:mod:`rfsas_hw.link.latency`). A
node given two transports (``--send A --fallback B``, any URLs the transport
factory opens) keeps its traffic on the primary while the primary is healthy
and moves it when the alarm rises:

- :class:`FallbackSender` sends on the primary. When its ``alarm`` is up (the
  latency watch of what this node *receives* on the primary: a channel jammed
  around a node is jammed both ways), or after ``error_alarm`` primary send
  errors in a row, it sends every datagram on the secondary, and a copy on the
  primary so that the far end can see the primary recover. Traffic returns to
  the primary only after the alarm has stayed down for ``hold_s`` (on top of
  the watch's own hysteresis), so a borderline primary does not flap.
- :class:`FallbackReceiver` verifies what arrives on both paths with one
  receiver each (each path has its own latency watch, so the primary's alarm
  is the primary's alone) and hands each message (sender, sequence number)
  out once, whichever path brought it first: no duplicate reaches the backend.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

from rfsas_hw.errors import LinkError
from rfsas_hw.link.receiver import Receiver, ReceiverConfig, VerifiedMessage
from rfsas_hw.link.replay import ReplayGuard
from rfsas_hw.link.signing import SenderKeys
from rfsas_hw.link.transport import Transport, open_transport

log = logging.getLogger(__name__)

Path = Literal["primary", "secondary"]


@dataclass(frozen=True, slots=True)
class FallbackConfig:
    """When a sender moves between its paths.

    Raises:
        ValueError: a negative hold time or an error threshold below 1.
    """

    hold_s: float = 2.0
    """Seconds the primary must stay healthy before traffic returns to it."""
    error_alarm: int = 3
    """Primary send errors in a row that raise the alarm by themselves."""

    def __post_init__(self) -> None:
        if self.hold_s < 0 or self.error_alarm < 1:
            raise ValueError("fallback hold_s must be >= 0 and error_alarm >= 1")


@dataclass(slots=True)
class FallbackStats:
    """What a fallback sender did."""

    primary: int = 0
    """Datagrams sent on the primary (copies while on the secondary included)."""
    secondary: int = 0
    """Datagrams sent on the secondary."""
    primary_errors: int = 0
    """Primary sends that failed."""
    switches: dict[str, int] = field(default_factory=lambda: {"to_secondary": 0, "to_primary": 0})
    """Moves between the paths."""

    def as_dict(self) -> dict[str, int]:
        """Flat counters."""
        return {
            "sent.primary": self.primary,
            "sent.secondary": self.secondary,
            "primary_errors": self.primary_errors,
            "switches.to_secondary": self.switches["to_secondary"],
            "switches.to_primary": self.switches["to_primary"],
        }


class FallbackSender(Transport):
    """A send-only transport over a primary and a secondary path (module docstring).

    Args:
        primary: the normal path.
        secondary: the out-of-band path.
        alarm: True while the primary is judged denied (e.g. the latency watch of
            this node's receiver on the primary); None: only send errors count.
        config: hold time and error threshold.
        clock: monotonic seconds.
    """

    def __init__(
        self,
        primary: Transport,
        secondary: Transport,
        alarm: Callable[[], bool] | None = None,
        config: FallbackConfig | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.primary = primary
        self.secondary = secondary
        self.alarm = alarm
        self.config = config or FallbackConfig()
        self.clock = clock
        self.stats = FallbackStats()
        self.active: Path = "primary"
        self._errors_in_row = 0
        self._bad_at = -float("inf")
        self._closed = False

    @classmethod
    def to_urls(
        cls,
        primary_url: str,
        secondary_url: str,
        alarm: Callable[[], bool] | None = None,
        config: FallbackConfig | None = None,
    ) -> FallbackSender:
        """A sender over the transports two URLs name.

        Raises:
            LinkError: a bad URL or a socket that cannot be opened.
        """
        primary = open_transport(primary_url, "send")
        try:
            secondary = open_transport(secondary_url, "send")
        except BaseException:
            primary.close()
            raise
        return cls(primary, secondary, alarm, config)

    def _update(self) -> None:
        now = self.clock()
        bad = self._errors_in_row >= self.config.error_alarm or bool(
            self.alarm is not None and self.alarm()
        )
        if bad:
            self._bad_at = now
            if self.active == "primary":
                self.active = "secondary"
                self.stats.switches["to_secondary"] += 1
                log.warning("primary path denied: sending on the secondary")
        elif self.active == "secondary" and now - self._bad_at >= self.config.hold_s:
            self.active = "primary"
            self._errors_in_row = 0
            self.stats.switches["to_primary"] += 1
            log.info("primary path healthy for %.1f s: back on it", self.config.hold_s)

    def _send_primary(self, datagram: bytes) -> bool:
        try:
            self.primary.send(datagram)
        except LinkError as err:
            self.stats.primary_errors += 1
            self._errors_in_row += 1
            if self._errors_in_row == 1:
                log.warning("primary send failed: %s", err)
            return False
        self.stats.primary += 1
        self._errors_in_row = 0
        return True

    def send(self, datagram: bytes) -> None:
        """Send on the active path (see the module docstring).

        Raises:
            LinkError: the datagram could not be sent on any path.
        """
        self._update()
        if self.active == "primary":
            if self._send_primary(datagram):
                return
            # this one must not be lost: it goes out of band right away
            self.secondary.send(datagram)
            self.stats.secondary += 1
            self._update()
            return
        sent = False
        try:
            self.secondary.send(datagram)
            self.stats.secondary += 1
            sent = True
        finally:
            # the copy lets the far end see the primary recover; a duplicate is refused there
            if self._send_primary(datagram):
                sent = True
            elif not sent:
                raise LinkError("datagram could not be sent on the primary nor the secondary")

    def recv(self, timeout: float | None = None) -> bytes | None:
        """Not available: a fallback sender only sends.

        Raises:
            LinkError: always.
        """
        raise LinkError("a fallback sender cannot receive; use FallbackReceiver")

    def refused(self) -> int:
        """What the far ends of both paths refused."""
        return self.primary.refused() + self.secondary.refused()

    def close(self) -> None:
        """Close both paths; idempotent."""
        if not self._closed:
            self._closed = True
            self.primary.close()
            self.secondary.close()


class FallbackReceiver:
    """Verified messages from a primary and a secondary path, each path watched, no duplicates.

    Each path's receiver checks (and refuses replays on) its own path and feeds its
    own latency watch with every authentic arrival, copies included, so the
    primary's watch sees it recover while traffic runs on the secondary. Across
    the paths a message (sender, sequence number) is handed out once; the later
    copy is counted in ``duplicates``.

    Args:
        primary: receiver on the primary path.
        secondary: receiver on the secondary path.
    """

    def __init__(self, primary: Receiver, secondary: Receiver) -> None:
        self.primary = primary
        self.secondary = secondary
        cfg = primary.config
        window_us = int((cfg.max_age_s + cfg.max_future_s) * 1_000_000)
        self._delivered = ReplayGuard(window_us, cfg.replay_capacity)
        self.duplicates = 0
        self.delivered: dict[str, int] = {"primary": 0, "secondary": 0}

    @classmethod
    def listen(
        cls,
        primary_url: str,
        secondary_url: str,
        trust: SenderKeys,
        config: ReceiverConfig | None = None,
        *,
        clock: Callable[[], int] = time.time_ns,
    ) -> FallbackReceiver:
        """Receivers listening on two URLs.

        Raises:
            LinkError: a bad URL or a socket that cannot be bound.
        """
        first = Receiver.listen(primary_url, trust, config=config, clock=clock)
        try:
            second = Receiver.listen(secondary_url, trust, config=config, clock=clock)
        except BaseException:
            first.close()
            raise
        return cls(first, second)

    @property
    def primary_alarm(self) -> bool:
        """True while the primary path's latency watch is in alarm (late or silent)."""
        return self.primary.latency.alarm

    def receive(
        self, timeout: float | None = None, poll_s: float = 0.002
    ) -> list[tuple[Path, VerifiedMessage]]:
        """What arrived on either path, each message once: returns as soon as something
        arrived on either, or after ``timeout`` seconds (None: wait), checking both
        paths every ``poll_s`` seconds so a stalled primary never delays the secondary."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            out: list[tuple[Path, VerifiedMessage]] = []
            arrived: list[tuple[Path, VerifiedMessage]] = [
                ("primary", m) for m in self.primary.receive(0)
            ]
            arrived += [("secondary", m) for m in self.secondary.receive(0)]
            for path, m in arrived:
                msg = m.message
                now_us = m.t_recv_ns // 1000
                if self._delivered.check_and_record(msg.sender_id, msg.seq, msg.t_gen_us, now_us):
                    out.append((path, m))
                    self.delivered[path] += 1
                else:
                    self.duplicates += 1
            if out:
                return out
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return out
            time.sleep(poll_s if left is None else min(poll_s, left))

    def close(self) -> None:
        """Close both receivers; idempotent."""
        self.primary.close()
        self.secondary.close()
