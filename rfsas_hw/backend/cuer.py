"""The backend's cues: vehicles are told where an emitter at risk can be heard.

A result sink of :class:`~rfsas_hw.backend.service.BackendService`: it
remembers the channel each emitter was last heard on (from the bearings the
backend takes) and, after each step, sends a signed *fix* cue
(:mod:`rfsas_hw.link.cue`) for every emitter the backend advises ``brake`` or
``caution`` about (or whose risk is at least ``min_risk``) and whose latest fix
can be trusted: the fix and its covariance,
the channel, the risk (the vehicles' schedulers serve the highest first), at
most one per emitter every ``every_s`` seconds, valid for ``valid_s`` after
the fix. Usage::

    cuer = BackendCuer(signer, open_transport("udp://239.255.42.2:47010", "send"))
    backend = BackendService(config, sinks=[cuer])
"""

from __future__ import annotations

import logging
import math
import secrets
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from rfsas_hw.errors import LinkError
from rfsas_hw.link.cue import Cue, CueKind, Phy, band_of, sign_cue
from rfsas_hw.link.cue_sender import CueSender, CueSendStats
from rfsas_hw.link.signing import Signer
from rfsas_hw.link.transport import Transport
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, NS_PER_S
from rfsas_hw.records import Assessment, BearingBatch, Fix, Pose

log = logging.getLogger(__name__)


@dataclass(slots=True)
class CuerStats(CueSendStats):
    """Cues the backend sent, and emitters at risk it did not cue, by reason:
    ``rate``, ``no_fix`` (no trusted fix), ``no_channel`` (never heard on Wi-Fi),
    ``invalid`` (a fix the cue cannot carry), ``send_error``."""


class BackendCuer(CueSender):
    """Sends fix cues for emitters at risk (see the module docstring).

    Args:
        signer: the backend's signing identity.
        transport: where cues go (to the vehicles); closed with the cuer.
        advisories: the advisories that earn a cue.
        min_risk: a risk that earns a cue whatever the advisory, 0–1 (None: advisories only).
        every_s: most one cue per emitter this often, seconds.
        valid_s: validity after the fix, seconds.
        epoch_s: nonce epoch length, seconds.
        clock: UTC ns.

    Raises:
        LinkError: ``min_risk`` outside [0, 1] or non-positive times.
    """

    def __init__(
        self,
        signer: Signer,
        transport: Transport,
        *,
        advisories: tuple[str, ...] = ("brake", "caution"),
        min_risk: float | None = None,
        every_s: float = 0.5,
        valid_s: float = 2.0,
        epoch_s: float = DEFAULT_EPOCH_S,
        clock: Callable[[], int] = time.time_ns,
    ) -> None:
        if (min_risk is not None and not 0.0 <= min_risk <= 1.0) or every_s <= 0 or valid_s <= 0:
            raise LinkError("backend cues: min_risk in [0, 1], every_s and valid_s > 0")
        self.advisories = frozenset(advisories)
        self.signer = signer
        self.transport = transport
        self.min_risk = min_risk
        self.every_ns = int(every_s * NS_PER_S)
        self.valid_ns = int(valid_s * NS_PER_S)
        self.epoch_ns = int(epoch_s * NS_PER_S)
        self.clock = clock
        self.seq = secrets.randbelow(1 << 32)
        self.stats = CuerStats()
        self._channel: dict[int, int] = {}
        self._fix: dict[int, Fix] = {}
        self._sent: dict[int, int] = {}
        self._closed = False

    def on_bearings(self, bearings: BearingBatch, pose: Pose) -> None:
        """Remember the channel each emitter was last heard on."""
        if len(bearings) == 0:
            return
        order = np.argsort(bearings.t_ns, kind="stable")
        for emitter, channel in zip(
            bearings.emitter[order].tolist(), bearings.channel[order].tolist(), strict=True
        ):
            self._channel[int(emitter)] = int(channel)

    def on_results(self, fixes: Sequence[Fix], assessments: Sequence[Assessment]) -> None:
        """Cue every emitter at risk with a trusted fix (rate-limited per emitter)."""
        for f in fixes:
            if f.ok:
                self._fix[int(f.emitter, 16)] = f
        now = self.clock()
        for a in assessments:
            at_risk = self.min_risk is not None and a.risk >= self.min_risk
            if a.advisory not in self.advisories and not at_risk:
                continue
            emitter = int(a.emitter, 16)
            last = self._sent.get(emitter)
            if last is not None and now - last < self.every_ns:
                self.stats.skipped["rate"] += 1
                continue
            fix = self._fix.get(emitter)
            if fix is None:
                self.stats.skipped["no_fix"] += 1
                continue
            if now >= fix.t_ns + self.valid_ns:
                # the newest trusted fix is older than a cue's validity: a cue would
                # arrive already expired (a late step, or fixes no longer trusted)
                self.stats.skipped["stale_fix"] += 1
                continue
            channel = self._channel.get(emitter)
            if channel is None or not _wifi(channel):
                self.stats.skipped["no_channel"] += 1
                continue
            self._send(emitter, fix, channel, min(float(a.risk), 1.0), now)

    def _send(self, emitter: int, fix: Fix, channel: int, risk: float, now: int) -> None:
        values = (fix.x_m, fix.y_m, fix.cov_xx_m2, fix.cov_xy_m2, fix.cov_yy_m2)
        if not all(math.isfinite(v) for v in values):
            self.stats.skipped["invalid"] += 1
            return
        cue = Cue(
            sender_id=self.signer.sender_id,
            t_gen_us=now // 1000,
            seq=self.seq,
            epoch=fix.t_ns // self.epoch_ns,
            emitter=emitter,
            t_obs_us=fix.t_ns // 1000,
            valid_until_us=(fix.t_ns + self.valid_ns) // 1000,
            channel=channel,
            band=band_of(channel),
            phy=Phy.UNKNOWN,
            kind=CueKind.FIX,
            risk=risk,
            x_m=fix.x_m,
            y_m=fix.y_m,
            a=fix.cov_xx_m2,
            b=fix.cov_xy_m2,
            c=fix.cov_yy_m2,
        )
        try:
            self.transport.send(sign_cue(self.signer, cue))
        except LinkError as err:
            key = "invalid" if "bad cue" in str(err) else "send_error"
            self.stats.skipped[key] += 1
            if self.stats.skipped[key] == 1:
                log.warning("backend cue not sent: %s", err)
            return
        self.seq = (self.seq + 1) % (1 << 32)
        self._sent[emitter] = now
        self.stats.cues += 1


def _wifi(channel: int) -> bool:
    try:
        band_of(channel)
    except LinkError:
        return False
    return True
