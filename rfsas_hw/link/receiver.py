"""Receiving safety messages: verify, check relevance, refuse replays, watch latency.

API (for a backend)::

    from rfsas_hw.link import Receiver, ReceiverConfig, TrustedKeys
    rx = Receiver(trust, nonces=None, config=ReceiverConfig())
    verified = rx.feed(datagram, t_recv_ns)   # VerifiedMessage | None, never raises
    rx.stats                                  # ReceiverStats: counts by rejection reason
    rx.latency                                # LatencyWatch: per-sender state (ok/late/silent)
    rx.refusals                               # RefusalWatch: senders all of whose messages
                                              # are refused, and why (skew, nonce, unenrolled)

    rx = Receiver.listen("udp://127.0.0.1:47000", trust)
    for msg in rx.receive(timeout=0.1): ...   # everything that arrived, verified

``trust`` is anything with ``signing_key(sender_id)`` (:class:`TrustedKeys`, or
the trust directory of a key store). A trust directory is refreshed by every
:meth:`Receiver.receive` call (it looks at the disk at most every ``reload_s``,
2 s by default): a sender revoked with ``rfsas keys revoke`` is refused as
``unknown_sender`` from then on, without a restart. ``nonces`` (optional) takes nonce
envelopes that arrive on the same port (see :mod:`rfsas_hw.privacy.nonces`).

Checks run cheapest first and in this order; the first failure decides the
reason a datagram is counted under:

1. structure (no cryptography): ``oversized``, ``truncated``, ``bad_magic``,
   ``bad_version``, ``bad_type``, ``malformed``; ``topic_mismatch`` (a broker
   topic that names another sender than the message); then ``unknown_sender``;
   ``v1_refused`` (a version-1 message, untagged, at a receiver that requires
   tags);
2. the header's times, compared with the receiver's clock (no cryptography):
   ``wrong_epoch`` (the nonce epoch is not one the receiver accepts now),
   ``stale`` (generated more than ``max_age_s`` ago), ``future`` (generated
   more than ``max_future_s`` ahead of the receiver's clock);
3. pre-authentication (version 2, one HMAC; :mod:`rfsas_hw.link.preauth`):
   ``no_preauth_key`` (a receiver that requires tags does not hold the epoch's
   nonce; one that reads version 1 goes on to the signature), ``bad_preauth``;
   then ``replay`` (an exact copy of a message already verified) and
   ``rate_limited`` (the sender's budget of signature checks per second is spent);
4. signature with the sender's enrolled key: ``bad_signature``;
5. relevance: ``too_far`` (sender farther than ``max_range_m`` from the
   receiver's position), ``wrong_epoch`` (a bearing captured outside the
   message's epoch);
6. replay: ``replay`` (sequence number already seen inside the window).

Steps 1 to 3 read bytes not authenticated yet, so they only ever refuse, never
accept: each refuses a message that must be refused whatever its signature, and
does so before the signature costs anything (about 0.1 ms of ECDSA
verify, against well under a microsecond for a time check: a receiver that
falls behind refuses the messages it got too late at almost no cost, and a
flood of old or forged-time messages costs no verify). A forged message that is
also too old is therefore counted ``stale``, not ``bad_signature``. What changes
state an attacker could abuse waits for the signature: the replay window (step
6) and the latency watch record only verified messages, and the rate limiter's
budget is spent only by messages that passed steps 1 to 3. The refusal watch
counts refusals per *claimed* sender id before the signature, bounded as its
module says.

:meth:`Receiver.receive` may also drop well-formed datagrams from enrolled
senders without a signature check under overload (``overload``); see its docstring.

Value checks on the bearings (``malformed``) run only on authenticated bytes.
A bug in a check is counted as ``internal_error`` and logged; :meth:`Receiver.feed`
never raises into the caller's loop.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.errors import LinkError, LinkSecurityError
from rfsas_hw.link.latency import LatencyConfig, LatencyWatch
from rfsas_hw.link.message import (
    MAX_DATAGRAM,
    TYPE_NONCE,
    MessageFormatError,
    Peeked,
    SafetyMessage,
    decode_peeked,
    header_epoch,
    peek,
    signed_part,
)
from rfsas_hw.link.preauth import NonceSource, PreauthKeys, RateLimiter, TagKey
from rfsas_hw.link.refusals import RefusalConfig, RefusalWatch
from rfsas_hw.link.replay import ReplayGuard
from rfsas_hw.link.signing import RefreshingKeys, SenderKeys, verify
from rfsas_hw.link.topics import ROOT as TOPIC_ROOT
from rfsas_hw.link.topics import topic_sender
from rfsas_hw.link.transport import Transport, open_transports
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, DEFAULT_GRACE_S, EpochSchedule
from rfsas_hw.records import BearingBatch

log = logging.getLogger(__name__)

NS_PER_US = 1000
US_PER_S = 1_000_000

REASONS = (
    "oversized",
    "truncated",
    "bad_magic",
    "bad_version",
    "bad_type",
    "malformed",
    "topic_mismatch",
    "unknown_sender",
    "v1_refused",
    "wrong_epoch",
    "stale",
    "future",
    "no_preauth_key",
    "bad_preauth",
    "rate_limited",
    "bad_signature",
    "too_far",
    "replay",
    "nonce_rejected",
    "nonce_unexpected",
    "overload",
    "internal_error",
)
"""Every reason a datagram can be rejected for, in check order (``wrong_epoch`` is
also the reason of a bearing captured outside its message's epoch, after the signature)."""


@dataclass(frozen=True, slots=True)
class ReceiverConfig:
    """Relevance and replay thresholds of a receiver.

    Raises:
        ValueError: on a non-positive age, skew or range.
    """

    max_age_s: float = 1.0
    """Messages generated longer ago than this are ``stale``, seconds."""
    max_future_s: float = 0.2
    """Allowed clock skew: messages generated further ahead are ``future``, seconds."""
    max_range_m: float = 2000.0
    """Senders farther than this from the receiver's position are ``too_far``, metres
    (checked only when the receiver knows its position)."""
    check_epoch: bool = True
    """Refuse messages whose nonce epoch the receiver does not accept now. Turn off
    to feed a receiver recorded messages from the past."""
    epoch_s: float = DEFAULT_EPOCH_S
    """Nonce epoch length, seconds (as the deployment's sensors use)."""
    grace_s: float = DEFAULT_GRACE_S
    """Grace period at an epoch boundary, seconds."""
    max_datagram: int = MAX_DATAGRAM
    """Largest datagram accepted, bytes."""
    replay_capacity: int = 4096
    """Most sequence numbers remembered per sender."""
    backlog: int = 256
    """Queued datagrams above which :meth:`Receiver.receive` checks newest first."""
    shed_after_s: float = 0.05
    """Signature-checking time one overloaded :meth:`Receiver.receive` call spends
    before it sheds the remaining signature checks, seconds."""
    latency: LatencyConfig = field(default_factory=LatencyConfig)
    """Latency watch thresholds."""
    refusals: RefusalConfig = field(default_factory=RefusalConfig)
    """Refusal watch thresholds (the alarm for a sender whose messages are all refused)."""
    accept_v1: bool = True
    """Accept version-1 messages (no pre-authentication tag). Turn off once every
    sensor sends version 2: only then does a forged flood cost one HMAC per datagram."""
    sender_rate_hz: float = 2000.0
    """Signature checks allowed per sender per second, on average."""
    sender_burst: float = 2000.0
    """Signature checks a sender may use at once."""

    def __post_init__(self) -> None:
        if self.max_age_s <= 0 or self.max_future_s < 0 or self.max_range_m <= 0:
            raise ValueError("max_age_s and max_range_m must be positive, max_future_s >= 0")
        if self.sender_rate_hz <= 0 or self.sender_burst < 1:
            raise ValueError("sender_rate_hz must be positive and sender_burst at least 1")

    @property
    def schedule(self) -> EpochSchedule:
        """The nonce epoch schedule."""
        return EpochSchedule(self.epoch_s, self.grace_s)


@dataclass(frozen=True, slots=True)
class VerifiedMessage:
    """A message that passed every check."""

    message: SafetyMessage
    """The decoded message."""
    t_recv_ns: int
    """When it was received, UTC ns (receiver clock)."""
    age_s: float
    """Generation → verified, seconds (negative when the sender's clock runs ahead)."""

    @property
    def sender_id(self) -> str:
        """Id of the verified sender."""
        return self.message.sender_id

    @property
    def bearings(self) -> BearingBatch:
        """The message's bearings (``sensor_id`` is the sender id)."""
        return self.message.bearings


@dataclass(slots=True)
class ReceiverStats:
    """What a receiver has seen: datagrams, verified messages, rejections by reason."""

    datagrams: int = 0
    verified: int = 0
    bearings: int = 0
    nonces: int = 0
    """Nonce envelopes accepted."""
    envelopes: int = 0
    """Nonce envelopes received, whatever became of them (accepted, refused by the nonce
    store, shed under overload, or failed): ``datagrams - envelopes`` are the safety
    messages received."""
    rejected: Counter[str] = field(default_factory=Counter)

    @property
    def rejected_total(self) -> int:
        """All rejections together."""
        return sum(self.rejected.values())

    def as_dict(self) -> dict[str, int]:
        """Flat counters, for a table or a JSON status line."""
        out = {
            "datagrams": self.datagrams,
            "verified": self.verified,
            "bearings": self.bearings,
            "nonces": self.nonces,
            "envelopes": self.envelopes,
        }
        out.update({f"rejected.{k}": v for k, v in sorted(self.rejected.items())})
        return out


class EnvelopeSink(Protocol):
    """Takes nonce envelopes (``rfsas_hw.privacy.nonces.NonceStore`` is one)."""

    def accept_envelope(self, datagram: bytes, now_ns: int) -> int:
        """Open and keep the nonce in ``datagram``; return its epoch.

        Raises:
            LinkSecurityError: the envelope is not for us, not authentic, or not wanted now.
        """
        ...


_BEARING_TOPICS = f"{TOPIC_ROOT}/bearing/"


def _names_other(topic: str, sender_id: str) -> bool:
    """True when ``topic`` is a bearing topic naming another sender than ``sender_id``
    (``topic_mismatch``). A topic under the sender's own prefix is answered without
    parsing it."""
    if topic.startswith(_BEARING_TOPICS) and topic.startswith(
        f"{sender_id}/", len(_BEARING_TOPICS)
    ):
        return False
    named = topic_sender(topic)
    return named is not None and named != sender_id


class _Pending:
    """A message that passed every check before its signature."""

    __slots__ = ("datagram", "head", "key")

    def __init__(self, datagram: bytes, head: Peeked, key: ec.EllipticCurvePublicKey) -> None:
        self.datagram = datagram
        self.head = head
        self.key = key


class _Deferred:
    """A copy of a message admitted earlier in the same batch: checked in full once
    that one is settled, so that it meets the replay checks as it would one by one."""


DEFERRED = _Deferred()


class _DeferError(Exception):
    pass


_BATCH = 64
"""Messages admitted before their signatures are checked together: the CPU's caches
then hold the signature code, not the checks around it, for a run of them."""


class _RejectError(Exception):
    def __init__(
        self, reason: str, detail: str = "", sender: str = "", offset_s: float | None = None
    ) -> None:
        super().__init__(detail or reason)
        self.reason = reason
        self.sender = sender
        """The sender id the message claims (empty when it is not known yet)."""
        self.offset_s = offset_s
        """Generation time minus receive time, seconds (``stale`` and ``future``)."""


class Receiver:
    """Verifies safety messages from enrolled senders (see the module docstring).

    Args:
        trust: enrolled signing keys, looked up by sender id.
        nonces: where nonce envelopes arriving on the link go (None: count them as
            ``nonce_unexpected``).
        config: thresholds.
        position: returns the receiver's own (x_m, y_m), or None when unknown;
            without it the ``too_far`` check is skipped.
        transport: where :meth:`receive` reads datagrams from.
        clock: UTC time in ns, for datagrams fed without a receive time.
        preauth: pre-authentication keys for version-2 messages (default: derived
            from ``nonces`` when it gives nonces, as a ``NonceStore`` does; without
            keys, version-2 messages are counted as ``no_preauth_key``).
    """

    def __init__(
        self,
        trust: SenderKeys,
        nonces: EnvelopeSink | None = None,
        config: ReceiverConfig | None = None,
        *,
        position: Callable[[], tuple[float, float] | None] | None = None,
        transport: Transport | None = None,
        clock: Callable[[], int] = time.time_ns,
        preauth: PreauthKeys | None = None,
    ) -> None:
        self.trust = trust
        self.nonces = nonces
        self.config = config or ReceiverConfig()
        self.position = position
        self.transport = transport
        self.clock = clock
        self.schedule = self.config.schedule
        self.stats = ReceiverStats()
        self.latency = LatencyWatch(self.config.latency)
        self.refusals = RefusalWatch(self.config.refusals)
        """Per-sender alarm for runs of refusals (clock skew, nonce mismatch, unenrolled)."""
        self._verify_s = 0.0
        window_us = int((self.config.max_age_s + self.config.max_future_s) * US_PER_S)
        self.replay = ReplayGuard(window_us, self.config.replay_capacity)
        if preauth is None and isinstance(nonces, NonceSource):
            preauth = PreauthKeys(nonces)
        self.preauth = preauth
        self._tag_keys: dict[tuple[str, int], TagKey] = {}
        """(sender id, epoch) → pre-authentication key made ready for tags, of the
        enrolled senders seen lately."""
        self._epochs_ms = -1
        self._epochs_ok: tuple[int, ...] = ()
        self.limiter = RateLimiter(
            self.config.sender_rate_hz, self.config.sender_burst, time.monotonic
        )
        self._refresh_trust = trust.refresh if isinstance(trust, RefreshingKeys) else None

    @classmethod
    def listen(
        cls,
        url: str | Sequence[str],
        trust: SenderKeys,
        nonces: EnvelopeSink | None = None,
        config: ReceiverConfig | None = None,
        *,
        position: Callable[[], tuple[float, float] | None] | None = None,
        clock: Callable[[], int] = time.time_ns,
        preauth: PreauthKeys | None = None,
    ) -> Receiver:
        """A receiver reading from the transport(s) ``url`` names (e.g.
        ``udp://127.0.0.1:47000``, ``mqtts://…``; several URLs: from all of them).

        Raises:
            LinkError: a URL is bad, a socket cannot be bound or a broker reached.
        """
        transport = open_transports([url] if isinstance(url, str) else list(url), "recv")
        return cls(
            trust,
            nonces,
            config,
            position=position,
            transport=transport,
            clock=clock,
            preauth=preauth,
        )

    def feed(self, datagram: bytes, t_recv_ns: int | None = None) -> VerifiedMessage | None:
        """Check one datagram received at ``t_recv_ns`` (UTC ns; default: the clock).

        Returns the verified message, or None (rejected and counted, or a nonce
        envelope consumed). Never raises.
        """
        return self._feed(datagram, self.clock() if t_recv_ns is None else int(t_recv_ns))

    def feed_from(
        self, datagram: bytes, topic: str | None, t_recv_ns: int | None = None
    ) -> VerifiedMessage | None:
        """:meth:`feed` for a datagram that arrived on a broker ``topic``: a bearing
        topic must name the message's sender (``topic_mismatch``). Never raises."""
        now = self.clock() if t_recv_ns is None else int(t_recv_ns)
        return self._feed(datagram, now, topic=topic)

    def _feed(
        self, datagram: bytes, now_ns: int, shed: bool = False, topic: str | None = None
    ) -> VerifiedMessage | None:
        self.stats.datagrams += 1
        pending = self._admit(datagram, now_ns, shed, topic)
        if not isinstance(pending, _Pending):
            return None
        return self._settle(pending, now_ns, self._verify(pending))

    def _admit(
        self,
        datagram: bytes,
        now_ns: int,
        shed: bool,
        topic: str | None,
        staged: set[tuple[str, int, int]] | None = None,
    ) -> _Pending | _Deferred | None:
        """Every check before the signature (steps 1 to 3 of the module docstring).
        The datagram, its header and the sender's key when they pass; None when it
        is rejected (counted) or was a nonce envelope. With ``staged`` (the
        (sender, seq, generation time) of messages admitted earlier in a batch whose
        signature is not checked yet): :data:`DEFERRED` for a copy of one of them,
        to be checked in full after it. Never raises."""
        try:
            return self._check(bytes(datagram), now_ns, shed, topic, staged)
        except _DeferError:
            return DEFERRED
        except (_RejectError, MessageFormatError) as rej:
            self._count_rejection(rej.reason, rej, datagram)
        except Exception:
            self._count_internal_error(datagram)
        return None

    def _verify(self, pending: _Pending) -> bool | None:
        """The signature check of an admitted message (step 4), timed for shedding;
        None when the check itself failed (a bug: :meth:`_settle` counts it)."""
        body, signature = signed_part(pending.datagram)
        started = time.perf_counter()
        try:
            valid: bool | None = verify(pending.key, body, signature)
        except Exception:
            valid = None
        self._verify_s += time.perf_counter() - started
        return valid

    def _settle(self, pending: _Pending, now_ns: int, valid: bool | None) -> VerifiedMessage | None:
        """Steps 4 to 6 for an admitted message whose signature was found ``valid`` or
        not (None: its check failed): the verified message, or None (rejected,
        counted). Never raises."""
        datagram = pending.datagram
        try:
            if valid is None:
                raise RuntimeError("the signature check failed")
            if not valid:
                raise _RejectError("bad_signature", pending.head.sender_id)
            verified = self._accept(datagram, pending.head, now_ns)
        except (_RejectError, MessageFormatError) as rej:
            self._count_rejection(rej.reason, rej, datagram)
            return None
        except Exception:
            self._count_internal_error(datagram)
            return None
        self.stats.verified += 1
        self.stats.bearings += len(verified.message.bearings)
        self.refusals.verified(verified.sender_id)
        self.latency.observe(verified.sender_id, verified.age_s, now_ns, verified.message.seq)
        return verified

    def _count_rejection(self, reason: str, why: Exception, datagram: bytes) -> None:
        self.stats.rejected[reason] += 1
        if isinstance(why, _RejectError) and why.sender:
            self.refusals.refused(why.sender, reason, why.offset_s)
        if log.isEnabledFor(logging.DEBUG):
            log.debug("rejected %d-byte datagram: %s (%s)", len(datagram), reason, why)

    def _count_internal_error(self, datagram: bytes) -> None:
        self.stats.rejected["internal_error"] += 1
        if self.stats.rejected["internal_error"] == 1:
            log.exception("receiver check failed on a %d-byte datagram", len(datagram))

    def _check(
        self,
        datagram: bytes,
        now_ns: int,
        shed: bool,
        topic: str | None = None,
        staged: set[tuple[str, int, int]] | None = None,
    ) -> _Pending | None:
        """Steps 1 to 3 of the module docstring, in that order: the admitted message,
        or None for a nonce envelope (taken).

        Raises:
            _RejectError, MessageFormatError: the reason it is refused.
            _DeferError: a copy of a message of ``staged`` (admitted earlier in the same
                batch, signature not checked yet).
        """
        cfg = self.config
        head = peek(datagram, cfg.max_datagram)  # MessageFormatError is a rejection too
        if head.kind == TYPE_NONCE:
            self.stats.envelopes += 1
            if shed:  # opening one costs two key agreements
                raise _RejectError("overload", "nonce envelope")
            self._envelope(datagram, now_ns)
            return None
        sender = head.sender_id
        if topic is not None and _names_other(topic, sender):
            raise _RejectError("topic_mismatch", f"{sender} on {topic}")
        key = self.trust.signing_key(sender)
        if key is None:
            raise _RejectError("unknown_sender", sender, sender)
        if not self._preauthenticate(datagram, head, now_ns, staged):
            # a forged flood's way out: counted here, without raising
            self.stats.rejected["bad_preauth"] += 1
            self.refusals.refused(sender, "bad_preauth")
            return None
        if shed:
            raise _RejectError("overload", sender)
        return _Pending(datagram, head, key)

    def _accept(self, datagram: bytes, head: Peeked, now_ns: int) -> VerifiedMessage:
        """Relevance and replay of a message with a valid signature (steps 5 and 6);
        its age and epoch were checked before the signature (step 2)."""
        msg = decode_peeked(datagram, head)
        now_us = now_ns // NS_PER_US
        self._check_range(msg)
        if self.config.check_epoch:
            self._check_capture_epoch(msg)
        if not self.replay.check_and_record(msg.sender_id, msg.seq, msg.t_gen_us, now_us):
            raise _RejectError("replay", f"{msg.sender_id} seq {msg.seq}")
        return VerifiedMessage(msg, now_ns, (now_us - msg.t_gen_us) / US_PER_S)

    def _check_times(self, sender: str, t_gen_us: int, epoch: int, now_ns: int) -> None:
        """Step 2: the header's epoch and generation time against the receiver's clock.

        Raises:
            _RejectError: ``wrong_epoch``, ``stale`` or ``future``.
        """
        cfg = self.config
        if cfg.check_epoch and epoch not in self._accepted_epochs(now_ns):
            raise _RejectError("wrong_epoch", f"{sender} epoch {epoch}", sender)
        age_us = now_ns // NS_PER_US - t_gen_us
        if age_us > cfg.max_age_s * US_PER_S:
            raise _RejectError(
                "stale", f"{sender} age {age_us / 1e3:.1f} ms", sender, -age_us / 1e6
            )
        if -age_us > cfg.max_future_s * US_PER_S:
            raise _RejectError(
                "future", f"{sender} {-age_us / 1e3:.1f} ms ahead", sender, -age_us / 1e6
            )

    def _preauthenticate(
        self,
        datagram: bytes,
        head: Peeked,
        now_ns: int,
        staged: set[tuple[str, int, int]] | None = None,
    ) -> bool:
        """The cheap checks before the signature (steps 2 and 3): the header's times,
        pre-authentication tag, exact copies of verified messages, the sender's budget
        of signature checks. False when the tag is wrong (``bad_preauth``).

        Raises:
            _RejectError: another reason; _DeferError: a copy of a staged message.
        """
        sender = head.sender_id
        t_gen_us, seq, epoch = header_epoch(datagram, head)
        if not head.preauth and not self.config.accept_v1:
            raise _RejectError(
                "v1_refused",
                f"{sender}: version 1 has no pre-authentication tag; "
                "this receiver requires version 2",
            )
        self._check_times(sender, t_gen_us, epoch, now_ns)
        if head.preauth:
            tag = self._tag_key(sender, epoch)
            if tag is None:
                # without the epoch's nonce the tag cannot be checked: a receiver that
                # requires pre-authentication refuses, one that reads version 1 treats
                # the message like version 1 (the signature still decides)
                if not self.config.accept_v1:
                    raise _RejectError("no_preauth_key", f"{sender} epoch {epoch}", sender)
            elif not tag.tag_ok(datagram):
                return False
        if self.replay.seen(sender, seq, t_gen_us):
            raise _RejectError("replay", f"{sender} seq {seq} (copy)")
        if staged is not None and (sender, seq, t_gen_us) in staged:
            # a copy of a message whose signature is not checked yet: decide after it
            raise _DeferError
        if not self.limiter.allow(sender):
            raise _RejectError("rate_limited", sender)
        return True

    def _tag_key(self, sender_id: str, epoch: int) -> TagKey | None:
        """The pre-authentication key of an enrolled sender in an accepted epoch, made
        ready for tags once and kept (None: the epoch's nonce is not held)."""
        key = None if self.preauth is None else self.preauth.key_for(sender_id, epoch)
        if key is None:
            return None
        pair = (sender_id, epoch)
        tag = self._tag_keys.get(pair)
        if tag is None or tag.key != key:
            if len(self._tag_keys) >= 4096:
                self._tag_keys.clear()
            tag = self._tag_keys[pair] = TagKey(key)
        return tag

    def _accepted_epochs(self, now_ns: int) -> tuple[int, ...]:
        # a flood asks this for every datagram: answer from the last millisecond's result
        ms = now_ns // 1_000_000
        if ms != self._epochs_ms:
            self._epochs_ms = ms
            self._epochs_ok = self.schedule.accepted_epochs(now_ns)
        return self._epochs_ok

    def _check_range(self, msg: SafetyMessage) -> None:
        if self.position is None:
            return
        here = self.position()
        if here is None:
            return
        dist_m = math.hypot(msg.pose.x_m - here[0], msg.pose.y_m - here[1])
        if dist_m > self.config.max_range_m:
            raise _RejectError("too_far", f"{msg.sender_id} at {dist_m:.0f} m")

    def _check_capture_epoch(self, msg: SafetyMessage) -> None:
        # a message holds a few bearings: Python's min and max of them cost less than
        # numpy's reductions
        t_ns = msg.bearings.t_ns.tolist()
        epoch_ns = self.schedule.epoch_ns
        if not (min(t_ns) // epoch_ns == msg.epoch == max(t_ns) // epoch_ns):
            raise _RejectError("wrong_epoch", f"{msg.sender_id}: bearing outside epoch {msg.epoch}")

    def _envelope(self, datagram: bytes, now_ns: int) -> None:
        if self.nonces is None:
            raise _RejectError("nonce_unexpected")
        try:
            self.nonces.accept_envelope(datagram, now_ns)
        except (LinkSecurityError, LinkError) as err:
            raise _RejectError("nonce_rejected", str(err)) from None
        self.stats.nonces += 1

    def receive(
        self, timeout: float | None = None, max_datagrams: int = 4096
    ) -> list[VerifiedMessage]:
        """Wait up to ``timeout`` seconds for datagrams, drain what is queued (at most
        ``max_datagrams``), check them and return the verified messages. Also updates
        the latency watch's silence detection.

        Under overload (more than ``config.backlog`` datagrams queued) the newest are
        checked first, and once ``config.shed_after_s`` has been spent on signature
        checks the rest still get the cheap structural checks but no signature check
        (nor envelope decryption): those that pass them are counted as ``overload``.
        Junk that fails the cheap checks costs no budget, so it never pushes a valid
        message out; a flood of forged signatures delays valid messages by at most
        the budget instead of by the whole socket queue.

        Otherwise they are checked in arrival order, in runs of up to 64: the
        checks before the signature for each message of a run, then the run's
        signatures, then the checks after them. Every message meets the same
        checks in the same order as with :meth:`feed`, and a copy of a message of
        the same run is checked after that one is settled (so it costs no
        signature check when that one was verified).

        Raises:
            LinkError: the receiver has no transport.
        """
        if self.transport is None:
            raise LinkError("this receiver has no transport; use Receiver.listen(url, ...)")
        if self._refresh_trust is not None:
            self._refresh_trust()
        queued = self.transport.recv_many(timeout, max_datagrams)
        out: list[VerifiedMessage] = []
        overloaded = len(queued) > self.config.backlog
        if overloaded:
            queued.reverse()
        self._verify_s = 0.0
        if not overloaded:
            out = self._check_batch(queued)
            self.latency.poll(self.clock())
            return out
        shed = False
        clock = self.clock
        for i, (item, topic) in enumerate(queued):
            # the newest datagram is always checked in full, so every call makes progress
            shed = shed or (overloaded and i > 0 and self._verify_s > self.config.shed_after_s)
            verified = self._feed(item, clock(), shed, topic)
            if verified is not None:
                out.append(verified)
        if overloaded:
            out.reverse()
        self.latency.poll(self.clock())
        return out

    def _check_batch(self, queued: list[tuple[bytes, str | None]]) -> list[VerifiedMessage]:
        """Check ``queued`` (not overloaded: nothing is shed) in runs of :data:`_BATCH`:
        the checks before the signature for each message of a run in order, then
        the signatures, then the checks after them in order. Each message meets
        the same checks in the same order as one at a time; a copy of a message
        of the same run waits until that one is settled and is then checked in full."""
        out: list[VerifiedMessage] = []
        clock = self.clock
        stats = self.stats
        for start in range(0, len(queued), _BATCH):
            admitted: list[tuple[_Pending | tuple[bytes, str | None], int]] = []
            staged: set[tuple[str, int, int]] = set()
            for item, topic in queued[start : start + _BATCH]:
                now_ns = clock()
                stats.datagrams += 1
                pending = self._admit(item, now_ns, False, topic, staged)
                if isinstance(pending, _Pending):
                    t_gen_us, seq, _ = header_epoch(pending.datagram, pending.head)
                    staged.add((pending.head.sender_id, seq, t_gen_us))
                    admitted.append((pending, now_ns))
                elif pending is DEFERRED:
                    admitted.append(((item, topic), now_ns))
            valid = [self._verify(p) if isinstance(p, _Pending) else None for p, _ in admitted]
            for (entry, now_ns), ok in zip(admitted, valid, strict=True):
                if isinstance(entry, _Pending):
                    verified = self._settle(entry, now_ns, ok)
                else:
                    again = self._admit(entry[0], now_ns, False, entry[1])
                    verified = (
                        self._settle(again, now_ns, self._verify(again))
                        if isinstance(again, _Pending)
                        else None
                    )
                if verified is not None:
                    out.append(verified)
        return out

    def counters(self) -> dict[str, int]:
        """:attr:`stats` flat, the latency watch's state changes by the state entered
        (``latency.to_ok``, ``latency.to_late``, ``latency.to_silent``), plus the
        counters of broker transports (``mqtt.sent``, ``mqtt.received``,
        ``mqtt.dropped``, ``mqtt.disconnects``, …; summed over several)."""
        out = self.stats.as_dict()
        out.update({f"latency.to_{k}": v for k, v in sorted(self.latency.changes.items())})
        parts = getattr(self.transport, "transports", {self: self.transport})
        for transport in parts.values():
            stats = getattr(transport, "stats", None)
            if stats is not None and hasattr(stats, "as_dict"):
                for key, value in stats.as_dict().items():
                    out[f"mqtt.{key}"] = out.get(f"mqtt.{key}", 0) + int(value)
        return out

    def close(self) -> None:
        """Close the transport, if any; idempotent."""
        if self.transport is not None:
            self.transport.close()
