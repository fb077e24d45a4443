"""Nonce distribution over the link: the authority's sender and a receiver's inbox.

:class:`NonceDistributor` sends every enrolled receiver the envelopes of the
current and the next epoch (ahead of time), and sends them again every
``resend_s`` seconds, because UDP may lose a datagram and a receiver may
start late. :class:`NonceInbox` is the receiving end for a sensor, which
hashes with the nonces but does not otherwise listen on the link (a backend's
:class:`~rfsas_hw.link.receiver.Receiver` takes envelopes on its own port).
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable, Mapping

from rfsas_hw.errors import LinkError
from rfsas_hw.link.transport import Transport
from rfsas_hw.privacy.epochs import NS_PER_S
from rfsas_hw.privacy.hashing import NonceExpiredError, NonceUnavailableError
from rfsas_hw.privacy.nonces import NonceAuthority, NonceEnvelopeError, NonceStore

log = logging.getLogger(__name__)


class NonceDistributor:
    """Keeps every enrolled receiver supplied with the current and next epoch's nonce.

    Args:
        authority: the nonce authority (its enrolled receivers are who gets envelopes).
        destinations: receiver id → transport reaching it; enrolled receivers
            without one are skipped (and logged once).
        resend_s: seconds between sends of the same envelope.
        ahead: how many future epochs to hand out besides the current one.
        clock: UTC ns.

    Raises:
        ValueError: on a non-positive resend interval or negative ``ahead``.
    """

    def __init__(
        self,
        authority: NonceAuthority,
        destinations: Mapping[str, Transport],
        *,
        resend_s: float = 5.0,
        ahead: int = 1,
        clock: Callable[[], int] = time.time_ns,
    ) -> None:
        if resend_s <= 0 or ahead < 0:
            raise ValueError("resend_s must be positive and ahead non-negative")
        self.authority = authority
        self.destinations = dict(destinations)
        self.resend_ns = int(resend_s * NS_PER_S)
        self.ahead = ahead
        self.clock = clock
        self.sent: Counter[str] = Counter()
        """Envelopes sent, per receiver id."""
        self.errors: Counter[str] = Counter()
        """Sends that failed, per receiver id."""
        self.failing: set[str] = set()
        """Receivers whose last send failed (each start and end of a failure is logged)."""
        self._last: dict[tuple[str, int], int] = {}
        self._unreachable: set[str] = set()

    def tick(self, now_ns: int | None = None) -> int:
        """Send what is due at ``now_ns`` (UTC ns; default: the clock); return how many."""
        now = self.clock() if now_ns is None else now_ns
        epochs = self.authority.due(now, self.ahead)
        count = 0
        for rid in self.authority.receivers:
            transport = self.destinations.get(rid)
            if transport is None:
                if rid not in self._unreachable:
                    self._unreachable.add(rid)
                    log.warning(
                        "receiver %s is enrolled but has no address; it gets no nonces", rid
                    )
                continue
            for epoch in epochs:
                last = self._last.get((rid, epoch))
                if last is not None and now - last < self.resend_ns:
                    continue
                try:
                    transport.send(self.authority.seal(rid, epoch))
                except (LinkError, NonceEnvelopeError) as err:
                    self.errors[rid] += 1
                    if rid not in self.failing:
                        self.failing.add(rid)
                        log.warning("nonces for %s cannot be sent (%s); retrying", rid, err)
                    continue
                if rid in self.failing:
                    self.failing.discard(rid)
                    log.warning("nonces for %s are sent again", rid)
                self._last[(rid, epoch)] = now
                self.sent[rid] += 1
                count += 1
        oldest = epochs[0]
        self._last = {k: v for k, v in self._last.items() if k[1] >= oldest}
        return count

    def close(self) -> None:
        """Close every destination transport."""
        for transport in self.destinations.values():
            transport.close()


class NonceInbox:
    """Takes nonce envelopes from a transport into a :class:`NonceStore`.

    Also a :class:`~rfsas_hw.privacy.hashing.NonceProvider`: a sensor's hasher
    can ask it directly, and each request first takes whatever envelopes have
    arrived, so a sensor loop needs no separate polling.

    Args:
        store: where opened nonces go.
        transport: where envelopes arrive.
        clock: UTC ns.
        wait_s: how long :meth:`nonce_for` waits for a missing nonce to arrive
            (at start-up the first envelope may still be on its way).
    """

    def __init__(
        self,
        store: NonceStore,
        transport: Transport,
        clock: Callable[[], int] = time.time_ns,
        wait_s: float = 0.0,
    ) -> None:
        self.store = store
        self.transport = transport
        self.clock = clock
        self.wait_s = wait_s
        self.accepted = 0
        self.rejected = 0
        """Envelopes refused (malformed, not for us, not authentic, unwanted epoch)."""

    def poll(self, timeout: float | None = 0.0) -> int:
        """Wait up to ``timeout`` seconds, take every queued envelope; return how many
        were accepted. Never raises on a bad envelope (it is counted)."""
        accepted = 0
        datagram = self.transport.recv(timeout)
        while datagram is not None:
            try:
                self.store.accept_envelope(datagram, self.clock())
            except NonceEnvelopeError as err:
                self.rejected += 1
                log.debug("refused a nonce envelope: %s", err)
            else:
                accepted += 1
            datagram = self.transport.recv(0)
        self.accepted += accepted
        return accepted

    def nonce_for(self, epoch: int) -> bytes:
        """The nonce of ``epoch``, taking arrived envelopes first.

        Raises:
            NonceUnavailableError: not received within ``wait_s``, or expired.
        """
        self.poll(0.0)
        deadline = time.monotonic() + self.wait_s
        while True:
            try:
                return self.store.nonce_for(epoch)
            except NonceExpiredError:
                raise  # waiting cannot bring it back
            except NonceUnavailableError:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise
                self.poll(min(left, 0.1))

    def close(self) -> None:
        """Close the transport."""
        self.transport.close()
