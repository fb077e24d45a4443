"""The backend's signed assessments (message type 4): encode, sign, publish, verify.

Byte layout (big-endian; the common envelope of :mod:`rfsas_hw.link.message`)::

    off     size  field
    0       2     magic "RF"
    2       1     version: 1 (signed) or 2 (signed, then pre-authentication tag)
    3       1     type = 4 (advisory)
    4       1     flags, reserved, 0
    5       1     L = backend id length, 1..32
    6       L     backend id, ASCII [A-Za-z0-9._-]
    6+L     8     generation time, UTC µs, int64
    14+L    4     sequence number, uint32
    18+L    8     nonce epoch of the emitter ids, uint64
    26+L    1     V = vehicle id length, 0..32 (0: for every vehicle in the tile)
    27+L    V     vehicle id the assessments were judged against
    27+L+V  1     N = assessment count, 1..20
    28+L+V  62·N  assessments, each:
                    +0  8  time the assessment refers to, UTC µs, int64
                    +8  8  emitter id (keyed MAC hash), uint64
                    +16 4  x, east, metres, float32 (NaN: not located)
                    +20 4  y, north, metres, float32
                    +24 4  covariance xx, m², float32
                    +28 4  covariance xy, m², float32
                    +32 4  covariance yy, m², float32
                    +36 4  velocity east, m/s, float32
                    +40 4  velocity north, m/s, float32
                    +44 4  P(collision), float32 (NaN: no vehicle state)
                    +48 4  risk, float32
                    +52 4  time to closest approach, s, float32
                    +56 4  impact speed, m/s, float32
                    +60 1  advisory: 0 none, 1 clear, 2 caution, 3 brake
                    +61 1  flags: bit 0 fix ok, bit 1 link latency alarm
    end-64(-8) 64 ECDSA P-256 signature over every byte before it (the backend's key)
    end-8   8     version 2 only: pre-authentication tag (:mod:`rfsas_hw.link.preauth`)

A vehicle verifies advisories with the backends' enrolled keys
(:class:`AdvisoryReceiver`); two backends of an active/active pair send the
same assessments, and the vehicle keeps the newest per emitter.
"""

from __future__ import annotations

import math
import struct
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.errors import ConfigError, LinkError
from rfsas_hw.fleet.advisory_limits import AdvisoryLimiter, AdvisoryLimits
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link.message import (
    MAX_DATAGRAM,
    PREAUTH_BYTES,
    SIGNATURE_BYTES,
    TYPE_ADVISORY,
    VERSION,
    VERSION_PREAUTH,
    MessageFormatError,
    check_sender_id,
    pack_prefix,
    peek_prefix,
    signed_part,
)
from rfsas_hw.link.preauth import PreauthKeys, RateLimiter, sign_datagram, tag_ok
from rfsas_hw.link.replay import ReplayGuard
from rfsas_hw.link.sendcount import send_counters, send_problem
from rfsas_hw.link.signing import Signer, verify
from rfsas_hw.link.topics import ROOT, Route, TopicRouter, advisory_topic, vehicle_topic
from rfsas_hw.link.transport import Transport
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.records import Assessment, Fix, emitter_hex

MAX_ITEMS = 20
"""Most assessments per message (fits 1472 bytes with the longest ids)."""
ADVICE = ("none", "clear", "caution", "brake")
_HEAD = struct.Struct(">qIQ")
_ITEM = np.dtype(
    [
        ("t_us", ">i8"),
        ("emitter", ">u8"),
        ("f", ">f4", (11,)),
        ("advisory", "u1"),
        ("flags", "u1"),
    ]
)
ITEM_BYTES = _ITEM.itemsize


@dataclass(frozen=True, slots=True)
class AdvisoryItem:
    """One emitter's assessment as it travels (the wire subset of an Assessment)."""

    t_ns: int
    """Time the assessment refers to, UTC ns (µs resolution on the wire)."""
    emitter: str
    """Emitter id, 16 hex digits (keyed hash; never a MAC)."""
    x_m: float
    y_m: float
    cov_xx_m2: float
    cov_xy_m2: float
    cov_yy_m2: float
    vx_mps: float
    vy_mps: float
    p_collision: float
    risk: float
    t_closest_s: float
    impact_speed_mps: float
    advisory: str
    """``none``, ``clear``, ``caution`` or ``brake``."""
    fix_ok: bool
    link_alarm: bool

    @classmethod
    def of(cls, a: Assessment) -> AdvisoryItem:
        """The wire subset of an assessment."""
        return cls(
            a.t_ns,
            a.emitter,
            a.x_m,
            a.y_m,
            a.cov_xx_m2,
            a.cov_xy_m2,
            a.cov_yy_m2,
            a.vx_mps,
            a.vy_mps,
            a.p_collision,
            a.risk,
            a.t_closest_s,
            a.impact_speed_mps,
            a.advisory if a.advisory in ADVICE else "none",
            a.fix_ok,
            a.link_alarm,
        )


@dataclass(frozen=True, slots=True)
class AdvisoryMessage:
    """One signed advisory message, decoded."""

    sender_id: str
    """The backend that judged."""
    t_gen_us: int
    seq: int
    epoch: int
    vehicle_id: str
    """The vehicle judged against ('' when none)."""
    items: tuple[AdvisoryItem, ...]


def encode_advisory_body(msg: AdvisoryMessage, version: int = VERSION) -> bytes:
    """Every byte the signature covers.

    Raises:
        LinkError: a bad id, count, time, sequence number or epoch.
    """
    sender = check_sender_id(msg.sender_id)
    vehicle = check_sender_id(msg.vehicle_id) if msg.vehicle_id else b""
    n = len(msg.items)
    if not 1 <= n <= MAX_ITEMS:
        raise LinkError(f"an advisory carries 1-{MAX_ITEMS} assessments, got {n}")
    if not (0 <= msg.seq < 1 << 32 and 0 <= msg.epoch < 1 << 63 and msg.t_gen_us >= 0):
        raise LinkError("advisory sequence number, epoch or time out of range")
    for it in msg.items:
        if it.t_ns < 0:
            raise LinkError(f"assessment time {it.t_ns} before 1970")
    # every row in one call: per-field assignments into a structured array cost
    # microseconds each
    rows = np.array(
        [
            (
                it.t_ns // 1000,
                int(it.emitter, 16),
                (
                    it.x_m,
                    it.y_m,
                    it.cov_xx_m2,
                    it.cov_xy_m2,
                    it.cov_yy_m2,
                    it.vx_mps,
                    it.vy_mps,
                    it.p_collision,
                    it.risk,
                    it.t_closest_s,
                    it.impact_speed_mps,
                ),
                ADVICE.index(it.advisory),
                int(it.fix_ok) | (int(it.link_alarm) << 1),
            )
            for it in msg.items
        ],
        _ITEM,
    )
    head = pack_prefix(version, TYPE_ADVISORY, sender)
    fixed = _HEAD.pack(msg.t_gen_us, msg.seq, msg.epoch) + bytes([len(vehicle)]) + vehicle
    return head + fixed + bytes([n]) + rows.tobytes()


def sign_advisory(signer: Signer, msg: AdvisoryMessage, preauth_key: bytes | None = None) -> bytes:
    """The datagram of ``msg``: version 2 with ``preauth_key``, else version 1.

    Raises:
        LinkError: the message does not encode or names another sender.
    """
    return sign_datagram(
        signer, msg.sender_id, "advisory", lambda v: encode_advisory_body(msg, v), preauth_key
    )


@dataclass(frozen=True, slots=True)
class PeekedAdvisory:
    """What the cheap checks learn."""

    version: int
    sender_id: str
    vehicle_id: str
    n: int
    t_gen_us: int
    seq: int
    epoch: int


def peek_advisory(datagram: bytes) -> PeekedAdvisory:
    """Structural checks of an advisory (no cryptography).

    Raises:
        MessageFormatError: with ``reason`` naming the failed check.
    """
    version, kind, sender = peek_prefix(datagram)
    if kind != TYPE_ADVISORY:
        raise MessageFormatError("bad_type", f"message type {kind}, expected {TYPE_ADVISORY}")
    at = 6 + len(sender)
    size = len(datagram)
    if size < at + _HEAD.size + 2:
        raise MessageFormatError("truncated", f"{size} bytes")
    t_gen_us, seq, epoch = _HEAD.unpack_from(datagram, at)
    v_len = datagram[at + _HEAD.size]
    v_at = at + _HEAD.size + 1
    if size < v_at + v_len + 1:
        raise MessageFormatError("truncated", f"{size} bytes")
    vehicle = bytes(datagram[v_at : v_at + v_len])
    if v_len and not _id_ok(vehicle):
        raise MessageFormatError("malformed", f"vehicle id {vehicle!r}")
    n = datagram[v_at + v_len]
    if not 1 <= n <= MAX_ITEMS:
        raise MessageFormatError("malformed", f"{n} assessments")
    want = v_at + v_len + 1 + n * ITEM_BYTES + SIGNATURE_BYTES
    want += PREAUTH_BYTES if version == VERSION_PREAUTH else 0
    if size != want:
        raise MessageFormatError("truncated" if size < want else "oversized", f"{size} != {want}")
    return PeekedAdvisory(version, sender, vehicle.decode("ascii"), n, t_gen_us, seq, epoch)


def _id_ok(raw: bytes) -> bool:
    try:
        check_sender_id(raw.decode("ascii"))
    except (LinkError, UnicodeDecodeError):
        return False
    return True


def decode_advisory(datagram: bytes, head: PeekedAdvisory | None = None) -> AdvisoryMessage:
    """Parse an advisory (the signature is not checked here).

    Raises:
        MessageFormatError: structure or values invalid.
    """
    head = head or peek_advisory(datagram)
    at = 6 + len(head.sender_id) + _HEAD.size + 1 + len(head.vehicle_id) + 1
    items = []
    # the columns as Python values, one call each (fields of numpy scalars cost more
    # than the rows)
    rows = np.frombuffer(datagram, _ITEM, count=head.n, offset=at)
    for t_us, emitter, f, code, flags in zip(
        rows["t_us"].tolist(),
        rows["emitter"].tolist(),
        rows["f"].tolist(),
        rows["advisory"].tolist(),
        rows["flags"].tolist(),
        strict=True,
    ):
        if t_us < 0 or code >= len(ADVICE):
            raise MessageFormatError("malformed", "assessment time or advisory code")
        items.append(
            AdvisoryItem(
                t_ns=t_us * 1000,
                emitter=emitter_hex(emitter),
                x_m=f[0],
                y_m=f[1],
                cov_xx_m2=f[2],
                cov_xy_m2=f[3],
                cov_yy_m2=f[4],
                vx_mps=f[5],
                vy_mps=f[6],
                p_collision=f[7],
                risk=f[8],
                t_closest_s=f[9],
                impact_speed_mps=f[10],
                advisory=ADVICE[code],
                fix_ok=bool(flags & 1),
                link_alarm=bool(flags & 2),
            )
        )
    return AdvisoryMessage(
        head.sender_id, head.t_gen_us, head.seq, head.epoch, head.vehicle_id, tuple(items)
    )


def check_advisory_urls(urls: Sequence[str]) -> None:
    """Refuse a broker URL on which no advisory can arrive: without ``sub=`` or
    ``advisories=`` a listener subscribes to the bearing topics only, and ``tiles=``
    or ``nonces=`` alone name bearings and nonce envelopes. UDP URLs pass.

    Raises:
        ConfigError: such a URL (named, with what to add).
        LinkError: a malformed broker URL.
    """
    from rfsas_hw.link.mqtt import parse_mqtt_url

    not_advice = (f"{ROOT}/bearing/", f"{ROOT}/nonce/")
    for url in urls:
        if not url.startswith(("mqtt://", "mqtts://")):
            continue
        subs = parse_mqtt_url(url).subscriptions
        if not any(not s.startswith(not_advice) for s in subs):
            raise ConfigError(
                f"{url!r}: subscribes to no advisory topic, so nothing would arrive; add "
                "sub=rfsas/v1/vehicle/ID/advisory (this vehicle's) or advisories=TILES"
            )


class Publishing(Protocol):
    """A transport that publishes to a chosen topic (``MqttTransport``)."""

    def publish(self, route: Route, datagram: bytes) -> None:
        """Publish ``datagram`` as ``route`` says.

        Raises:
            LinkError: not sent.
        """
        ...


@dataclass(slots=True)
class AdvisorySinkStats:
    """What an advisory sink sent."""

    messages: int = 0
    assessments: int = 0
    errors: int = 0
    limited: int = 0
    """Assessments held back by the limits (:mod:`rfsas_hw.fleet.advisory_limits`)."""


class AdvisorySink:
    """A backend result sink that signs each step's assessments and publishes them on
    the advisory topic of each emitter's tile and, with ``vehicle_id``, on that
    vehicle's topic.

    Args:
        signer: the backend's signing identity.
        transport: a publishing transport (MQTT).
        router: places local metres in tiles (needs the site origin).
        home_tile: tile for assessments without a position (emitter heard, not located).
        vehicle_id: the vehicle the backend judges against ('' : none).
        preauth: the backend's pre-authentication keys (version 2), or None (version 1).
        epoch_s: nonce epoch length, seconds.
        clock: UTC ns.
        limits: how many assessments go out per emitter and per second
            (:class:`~rfsas_hw.fleet.advisory_limits.AdvisoryLimits`: by default one
            per emitter per 0.09 s unless its advice gets more severe, 100 per second).
        monotonic: monotonic seconds, for the limits.
        tile_topics: also publish on the tiles' advisory topics (False: on the
            vehicle's topic only, for a backend that judges many vehicles and keeps one
            sink per vehicle).
    """

    def __init__(
        self,
        signer: Signer,
        transport: Publishing,
        router: TopicRouter,
        home_tile: str,
        *,
        vehicle_id: str = "",
        preauth: PreauthKeys | None = None,
        epoch_s: float = 60.0,
        clock: Callable[[], int] = time.time_ns,
        limits: AdvisoryLimits | None = None,
        monotonic: Callable[[], float] = time.monotonic,
        tile_topics: bool = True,
    ) -> None:
        self.tile_topics = tile_topics
        self.limiter = AdvisoryLimiter(limits)
        self.monotonic = monotonic
        self.signer = signer
        self.transport = transport
        self.router = router
        self.home_tile = home_tile
        self.vehicle_id = vehicle_id
        self.preauth = preauth
        self.schedule = EpochSchedule(epoch_s, min(5.0, epoch_s / 4))
        self.clock = clock
        self.seq = int.from_bytes(np.random.default_rng().bytes(4), "big")
        self.stats = AdvisorySinkStats()
        self._owned: Transport | None = None

    def on_results(self, fixes: Sequence[Fix], assessments: Sequence[Assessment]) -> None:
        """Publish this step's assessments (nothing when there are none)."""
        if not assessments:
            return
        # the limits choose among the assessments; only the chosen become wire items
        chosen = [AdvisoryItem.of(a) for a in self.limiter.select(assessments, self.monotonic())]
        self.stats.limited = self.limiter.limited
        if not self.tile_topics:  # the vehicle's topic only: no tiles to sort them into
            if self.vehicle_id and chosen:
                self._send(Route(vehicle_topic(self.vehicle_id)), chosen, self.vehicle_id)
            return
        by_tile: dict[str, list[AdvisoryItem]] = {}
        for item in chosen:
            located = math.isfinite(item.x_m) and math.isfinite(item.y_m)
            tile = self.router.tile_of(item.x_m, item.y_m) if located else self.home_tile
            by_tile.setdefault(tile, []).append(item)
        items = [it for group in by_tile.values() for it in group]
        for tile, group in by_tile.items():
            self._send(Route(advisory_topic(tile)), group, "")
        if self.vehicle_id:
            self._send(Route(vehicle_topic(self.vehicle_id)), items, self.vehicle_id)

    def _send(self, route: Route, items: list[AdvisoryItem], vehicle: str) -> None:
        now_us = self.clock() // 1000
        epoch = self.schedule.epoch_of(now_us * 1000)
        key = None
        if self.preauth is not None:
            key = self.preauth.key_for(self.signer.sender_id, epoch)
        for start in range(0, len(items), MAX_ITEMS):
            chunk = tuple(items[start : start + MAX_ITEMS])
            msg = AdvisoryMessage(self.signer.sender_id, now_us, self.seq, epoch, vehicle, chunk)
            self.seq = (self.seq + 1) % (1 << 32)
            try:
                self.transport.publish(route, sign_advisory(self.signer, msg, key))
            except LinkError:
                self.stats.errors += 1
                continue
            self.stats.messages += 1
            self.stats.assessments += len(chunk)

    def _refused(self) -> int:
        refused = getattr(self.transport, "refused", None)
        return int(refused()) if callable(refused) else 0

    def counters(self) -> dict[str, int]:
        """Advisory messages ``sent``, ``failed``, ``refused`` by the broker, and
        ``dropped.limited`` assessments (:func:`~rfsas_hw.link.sendcount.send_counters`)."""
        st = self.stats
        return send_counters(st.messages, st.errors, self._refused(), {"limited": st.limited})

    def problem(self) -> str | None:
        """Why no advisory got through, or None
        (:func:`~rfsas_hw.link.sendcount.send_problem`)."""
        st = self.stats
        return send_problem("advisory messages", st.messages, st.errors, self._refused())

    def close(self) -> None:
        """Close the transport if this sink opened it; idempotent."""
        if self._owned is not None:
            self._owned.close()
            self._owned = None

    @classmethod
    def to_url(
        cls,
        url: str,
        signer: Signer,
        origin: SiteOrigin,
        *,
        vehicle_id: str = "",
        epoch_s: float = 60.0,
    ) -> AdvisorySink:
        """A sink publishing through the broker at ``url`` (``mqtt://``/``mqtts://``);
        assessments without a position go to the tile of the site origin.

        Raises:
            LinkError: not a broker URL, or no connection.
        """
        if not url.startswith(("mqtt://", "mqtts://")):
            raise LinkError(f"{url!r}: advisories are published to a broker (mqtt:// or mqtts://)")
        from rfsas_hw.link.mqtt import open_mqtt

        transport = open_mqtt(url, "send")
        router = TopicRouter(origin)
        sink = cls(
            signer,
            transport,
            router,
            router.tile_of(0.0, 0.0),
            vehicle_id=vehicle_id,
            epoch_s=epoch_s,
        )
        sink._owned = transport
        return sink


class BackendKeys(Protocol):
    """Enrolled backends' signing keys (a key store's trust directory)."""

    def backend_key(self, backend_id: str) -> ec.EllipticCurvePublicKey | None:
        """The P-256 key of ``backend_id``, or None when it is not enrolled."""
        ...


@dataclass(slots=True)
class AdvisoryStats:
    """What a vehicle's advisory receiver saw."""

    datagrams: int = 0
    verified: int = 0
    rejected: Counter[str] = field(default_factory=Counter)


class AdvisoryReceiver:
    """Verifies advisories at a vehicle and keeps the newest assessment per emitter.

    Checks, cheapest first: structure; addressed to another vehicle
    (``not_for_us``); backend enrolled (``unknown_sender``); age from the header
    (``stale``, ``future``); pre-authentication tag for version 2 when keys are
    given (``no_preauth_key``, ``bad_preauth``); exact copies (``replay``); the
    backend's budget of signature checks (``rate_limited``); signature
    (``bad_signature``); sequence number (``replay``). Everything before the
    signature only refuses (an advisory too old is refused before its signature
    costs anything, a forged one too old is counted ``stale``); the replay window
    records only verified advisories.

    Args:
        trust: enrolled backends' keys.
        transport: where advisories arrive.
        vehicle_id: this vehicle ('' : take every vehicle's).
        preauth: keys for version-2 advisories (None: those count as ``no_preauth_key``).
        max_age_s: older advisories are ``stale``, seconds.
        clock: UTC ns.
    """

    def __init__(
        self,
        trust: BackendKeys,
        transport: Transport | None = None,
        *,
        vehicle_id: str = "",
        preauth: PreauthKeys | None = None,
        max_age_s: float = 1.0,
        clock: Callable[[], int] = time.time_ns,
    ) -> None:
        self.trust = trust
        self.transport = transport
        self.vehicle_id = vehicle_id
        self.preauth = preauth
        self.max_age_us = int(max_age_s * 1e6)
        self.clock = clock
        self.stats = AdvisoryStats()
        self.replay = ReplayGuard(self.max_age_us + 200_000)
        self.limiter = RateLimiter(2000.0, 2000.0, time.monotonic)
        self.latest: dict[str, tuple[AdvisoryItem, str]] = {}
        """Emitter id → (newest assessment, backend that sent it)."""

    def feed(
        self, datagram: bytes, now_ns: int | None = None, head: PeekedAdvisory | None = None
    ) -> AdvisoryMessage | None:
        """Check one datagram; the verified message, or None (counted). Never raises.
        ``head``: :func:`peek_advisory` of this very datagram, when the caller already
        has it (a gateway that sorts datagrams by vehicle), so it is not parsed twice."""
        now = self.clock() if now_ns is None else now_ns
        self.stats.datagrams += 1
        try:
            msg = self._check(bytes(datagram), now, head)
        except MessageFormatError as err:
            self.stats.rejected[err.reason] += 1
            return None
        except _RejectError as rej:
            self.stats.rejected[str(rej)] += 1
            return None
        self.stats.verified += 1
        for it in msg.items:
            held = self.latest.get(it.emitter)
            if held is None or it.t_ns >= held[0].t_ns:
                self.latest[it.emitter] = (it, msg.sender_id)
        return msg

    def _check(
        self, datagram: bytes, now_ns: int, head: PeekedAdvisory | None = None
    ) -> AdvisoryMessage:
        if len(datagram) > MAX_DATAGRAM:
            raise MessageFormatError("oversized", f"{len(datagram)} bytes")
        if head is None:
            head = peek_advisory(datagram)
        if self.vehicle_id and head.vehicle_id not in ("", self.vehicle_id):
            raise _RejectError("not_for_us")
        key = self.trust.backend_key(head.sender_id)
        if key is None:
            raise _RejectError("unknown_sender")
        now_us = now_ns // 1000
        if now_us - head.t_gen_us > self.max_age_us:
            raise _RejectError("stale")
        if head.t_gen_us - now_us > 200_000:
            raise _RejectError("future")
        if head.version == VERSION_PREAUTH:
            pk = None if self.preauth is None else self.preauth.key_for(head.sender_id, head.epoch)
            if pk is None:
                raise _RejectError("no_preauth_key")
            if not tag_ok(pk, datagram):
                raise _RejectError("bad_preauth")
        if self.replay.seen(head.sender_id, head.seq, head.t_gen_us):
            raise _RejectError("replay")
        if not self.limiter.allow(head.sender_id):
            raise _RejectError("rate_limited")
        body, signature = signed_part(datagram)
        if not verify(key, body, signature):
            raise _RejectError("bad_signature")
        msg = decode_advisory(datagram, head)
        if not self.replay.check_and_record(msg.sender_id, msg.seq, msg.t_gen_us, now_us):
            raise _RejectError("replay")
        return msg

    def receive(self, timeout: float | None = None) -> list[AdvisoryMessage]:
        """Wait up to ``timeout`` s, check everything queued, return what verified.

        Raises:
            LinkError: the receiver has no transport.
        """
        if self.transport is None:
            raise LinkError("this advisory receiver has no transport")
        out = []
        got = self.transport.recv(timeout)
        while got is not None:
            msg = self.feed(got)
            if msg is not None:
                out.append(msg)
            got = self.transport.recv(0)
        return out


class _RejectError(Exception):
    """An advisory failed a check; the message is the reason."""
