"""Receiving cues: verify, check time, validity and epoch, refuse replays, count.

A vehicle's sensor obeys a cue only if it passed every check below, cheapest
first; the first failure decides the reason it is counted under:

1. structure: ``truncated``, ``oversized``, ``bad_magic``, ``bad_version``,
   ``bad_type``, ``malformed`` (before any cryptography), ``unknown_sender``;
2. the header's times: ``wrong_epoch`` (the nonce epoch is not one the
   receiver accepts now: the vehicle could not make a matching hash),
   ``stale`` (generated longer than ``max_age_s`` ago), ``future`` (ahead of
   the clock by more than ``max_future_s``);
3. for version 2, the pre-authentication tag: ``no_preauth_key`` (the epoch's
   nonce is not held), ``bad_preauth`` (an outsider's forgery: one HMAC spent);
4. ``bad_signature`` (forged or altered), then value checks (``malformed``),
   ``expired`` (its validity window has ended), ``too_far`` (cueing unit
   farther than ``max_range_m``);
5. ``replay`` (a sequence number of that sender already seen in the window).

The checks of step 2 can only refuse, so a cue refused there would be refused
after its signature too; made first, they cost no HMAC and no signature check
(a forged cue that is also too old is counted ``stale``). The replay window
records only verified cues, so a forgery cannot shut out a real one.

:meth:`CueReceiver.feed` never raises into the caller's loop.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from rfsas_hw.errors import LinkError
from rfsas_hw.link.cue import Cue, CueKind, decode_cue, peek_cue
from rfsas_hw.link.message import VERSION_PREAUTH, MessageFormatError, signed_part
from rfsas_hw.link.preauth import PreauthKeys, tag_ok
from rfsas_hw.link.replay import ReplayGuard
from rfsas_hw.link.signing import SenderKeys, verify
from rfsas_hw.link.transport import Transport
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, DEFAULT_GRACE_S, EpochSchedule
from rfsas_hw.records import BearingBatch, Pose
from rfsas_hw.sources.schedule import ChannelCue

log = logging.getLogger(__name__)

US_PER_S = 1_000_000

CUE_REASONS = (
    "truncated",
    "oversized",
    "bad_magic",
    "bad_version",
    "bad_type",
    "malformed",
    "unknown_sender",
    "wrong_epoch",
    "stale",
    "future",
    "no_preauth_key",
    "bad_preauth",
    "bad_signature",
    "expired",
    "too_far",
    "replay",
    "internal_error",
)
"""Every reason a cue can be rejected for, in check order."""


@dataclass(frozen=True, slots=True)
class CueReceiverConfig:
    """Thresholds of a cue receiver.

    Raises:
        ValueError: a non-positive age or range, or a negative skew.
    """

    max_age_s: float = 1.0
    """Cues generated longer ago than this are ``stale``, seconds."""
    max_future_s: float = 0.2
    """Allowed clock skew, seconds."""
    max_range_m: float = 2000.0
    """Cueing units farther than this from the receiver are ``too_far``, metres
    (only bearing cues carry the unit's position; checked when the receiver knows its own)."""
    epoch_s: float = DEFAULT_EPOCH_S
    """Nonce epoch length, seconds."""
    grace_s: float = DEFAULT_GRACE_S
    """Grace at an epoch boundary, seconds."""
    replay_capacity: int = 4096
    """Most sequence numbers remembered per sender."""

    def __post_init__(self) -> None:
        if self.max_age_s <= 0 or self.max_future_s < 0 or self.max_range_m <= 0:
            raise ValueError("max_age_s and max_range_m must be positive, max_future_s >= 0")


@dataclass(slots=True)
class CueReceiverStats:
    """Cue datagrams seen, accepted, and rejected by reason."""

    datagrams: int = 0
    accepted: int = 0
    rejected: Counter[str] = field(default_factory=Counter)

    def as_dict(self) -> dict[str, int]:
        """Flat counters."""
        out = {"datagrams": self.datagrams, "accepted": self.accepted}
        out.update({f"rejected.{k}": v for k, v in sorted(self.rejected.items())})
        return out


class _RejectError(Exception):
    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(detail or reason)
        self.reason = reason


class CueReceiver:
    """Verifies cues from enrolled cueing units (see the module docstring).

    Args:
        trust: enrolled signing keys by sender id.
        config: thresholds.
        position: the receiver's own (x_m, y_m), or None when unknown.
        transport: where :meth:`receive` reads datagrams from.
        clock: UTC ns.
        preauth: pre-authentication keys for version-2 cues (None: those are
            counted as ``no_preauth_key``).
    """

    def __init__(
        self,
        trust: SenderKeys,
        config: CueReceiverConfig | None = None,
        *,
        position: Callable[[], tuple[float, float] | None] | None = None,
        transport: Transport | None = None,
        clock: Callable[[], int] = time.time_ns,
        preauth: PreauthKeys | None = None,
    ) -> None:
        self.trust = trust
        self.preauth = preauth
        self.config = config or CueReceiverConfig()
        self.position = position
        self.transport = transport
        self.clock = clock
        self.schedule = EpochSchedule(self.config.epoch_s, self.config.grace_s)
        self.stats = CueReceiverStats()
        window_us = int((self.config.max_age_s + self.config.max_future_s) * US_PER_S)
        self.replay = ReplayGuard(window_us, self.config.replay_capacity)

    def feed(self, datagram: bytes, t_recv_ns: int | None = None) -> Cue | None:
        """Check one datagram received at ``t_recv_ns`` (UTC ns; default: the clock).

        Returns the cue, or None (rejected and counted). Never raises.
        """
        now_ns = self.clock() if t_recv_ns is None else int(t_recv_ns)
        self.stats.datagrams += 1
        try:
            cue = self._check(bytes(datagram), now_ns)
        except (_RejectError, MessageFormatError) as rej:
            self.stats.rejected[rej.reason] += 1
            log.debug("cue rejected: %s (%s)", rej.reason, rej)
            return None
        except Exception:
            self.stats.rejected["internal_error"] += 1
            if self.stats.rejected["internal_error"] == 1:
                log.exception("cue check failed on a %d-byte datagram", len(datagram))
            return None
        self.stats.accepted += 1
        return cue

    def _check(self, datagram: bytes, now_ns: int) -> Cue:
        cfg = self.config
        head = peek_cue(datagram)
        sender = head.sender_id
        key = self.trust.signing_key(sender)
        if key is None:
            raise _RejectError("unknown_sender", sender)
        if not self.schedule.accepts(head.epoch, now_ns):
            raise _RejectError("wrong_epoch", f"{sender} epoch {head.epoch}")
        now_us = now_ns // 1000
        age_us = now_us - head.t_gen_us
        if age_us > cfg.max_age_s * US_PER_S:
            raise _RejectError("stale", f"{sender} age {age_us / 1e3:.1f} ms")
        if -age_us > cfg.max_future_s * US_PER_S:
            raise _RejectError("future", f"{sender} {-age_us / 1e3:.1f} ms ahead")
        if head.version == VERSION_PREAUTH:
            pk = None if self.preauth is None else self.preauth.key_for(sender, head.epoch)
            if pk is None:
                raise _RejectError("no_preauth_key", f"{sender} epoch {head.epoch}")
            if not tag_ok(pk, datagram):
                raise _RejectError("bad_preauth", sender)
        body, signature = signed_part(datagram)
        if not verify(key, body, signature):
            raise _RejectError("bad_signature", sender)
        cue = decode_cue(datagram)
        if now_us > cue.valid_until_us:
            raise _RejectError("expired", f"{sender} seq {cue.seq}")
        here = self.position() if self.position is not None else None
        if here is not None and cue.kind is CueKind.BEARING:
            dist_m = math.hypot(cue.x_m - here[0], cue.y_m - here[1])
            if dist_m > cfg.max_range_m:
                raise _RejectError("too_far", f"{sender} at {dist_m:.0f} m")
        if not self.replay.check_and_record(sender, cue.seq, cue.t_gen_us, now_us):
            raise _RejectError("replay", f"{sender} seq {cue.seq}")
        return cue

    def receive(self, timeout: float | None = None, max_datagrams: int = 1024) -> list[Cue]:
        """Wait up to ``timeout`` seconds, check everything queued, return the accepted cues.

        Raises:
            LinkError: the receiver has no transport.
        """
        if self.transport is None:
            raise LinkError("this cue receiver has no transport")
        out: list[Cue] = []
        datagram = self.transport.recv(timeout)
        n = 0
        while datagram is not None and n < max_datagrams:
            cue = self.feed(datagram)
            if cue is not None:
                out.append(cue)
            n += 1
            datagram = self.transport.recv(0)
        return out

    def close(self) -> None:
        """Close the transport, if any; idempotent."""
        if self.transport is not None:
            self.transport.close()


def to_channel_cue(cue: Cue, now_utc_ns: int, now_s: float) -> ChannelCue:
    """A verified cue on a scheduler's clock: ``now_s`` there is ``now_utc_ns`` in UTC."""
    left_s = (cue.valid_until_us * 1000 - now_utc_ns) / 1e9
    return ChannelCue(cue.emitter, cue.channel, cue.risk, now_s + left_s)


def cue_bearing(cue: Cue) -> tuple[BearingBatch, Pose]:
    """The cueing unit's bearing carried by a bearing cue, for the association: one row
    under the unit's sensor id, with the keyed emitter id the vehicle's own bearing is
    matched by, and the unit's position (the heading is not sent: 0).

    Raises:
        LinkError: a fix cue (it carries a position, not a bearing).
    """
    if cue.kind is not CueKind.BEARING:
        raise LinkError(f"cue {cue.seq} from {cue.sender_id} carries a fix, not a bearing")
    batch = BearingBatch(
        sensor_id=cue.sender_id,
        t_ns=np.array([cue.t_obs_us * 1000], np.int64),
        azimuth_deg=np.array([cue.a]),
        sigma_deg=np.array([cue.b]),
        snr_db=np.array([np.nan]),
        channel=np.array([cue.channel], np.int16),
        emitter=np.array([cue.emitter], np.uint64),
    )
    return batch, Pose(cue.x_m, cue.y_m, 0.0)


class CueInbox:
    """Cues arriving on a cue receiver's transport, handed to a scan scheduler
    (:attr:`rfsas_hw.sources.schedule.CueScheduler.inbox`) on its clock.

    Args:
        receiver: a cue receiver with a transport.
    """

    def __init__(self, receiver: CueReceiver) -> None:
        self.receiver = receiver

    def poll(self, now_s: float) -> list[ChannelCue]:
        """Accepted cues waiting now (no wait), with expiry on the scheduler clock ``now_s``."""
        cues = self.receiver.receive(0)
        now_ns = self.receiver.clock()
        return [to_channel_cue(c, now_ns, now_s) for c in cues]

    def close(self) -> None:
        """Close the receiver's transport."""
        self.receiver.close()
