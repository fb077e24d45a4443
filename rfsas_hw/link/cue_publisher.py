"""Sending cues: a bearing listener that turns a roadside unit's bearings into signed cues.

For each emitter it has a bearing of, the unit sends at most one cue every
``every_s`` seconds: the emitter's keyed id and epoch, the channel the bearing
was measured on, the bearing itself and the unit's position, valid for
``valid_s`` after the bearing. Only hashed ids reach this stage (a
:class:`~rfsas_hw.records.BearingBatch` cannot hold a raw MAC).
"""

from __future__ import annotations

import logging
import math
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rfsas_hw.angles import wrap_deg_360
from rfsas_hw.errors import LinkError
from rfsas_hw.link.cue import Cue, CueKind, Phy, band_of, sign_cue
from rfsas_hw.link.cue_sender import CueSender, CueSendStats
from rfsas_hw.link.preauth import NonceSource, derive_key
from rfsas_hw.link.signing import Signer
from rfsas_hw.link.transport import Transport
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, NS_PER_S
from rfsas_hw.privacy.hashing import NonceUnavailableError
from rfsas_hw.records import BearingBatch, Pose

log = logging.getLogger(__name__)


@dataclass(slots=True)
class CuePublisherStats(CueSendStats):
    """Cues sent, and bearings not turned into cues by reason: ``rate`` (an emitter
    cued less than ``every_s`` ago), ``invalid``, ``not_wifi`` (a channel number
    outside the Wi-Fi bands), ``send_error``."""


class CuePublisher(CueSender):
    """Signs cues for a sensor's bearings and sends them (a ``BearingListener``).

    Args:
        signer: the unit's signing identity.
        transport: where cues go (closed with the publisher).
        pose: the unit's pose, or a function returning it.
        every_s: most one cue per emitter this often, seconds.
        valid_s: validity of a cue after its bearing, seconds.
        risk: the risk the cues carry (a roadside unit does not judge risk: 1).
        epoch_s: nonce epoch length, seconds.
        preauth: epoch nonces for version-2 cues (None: version 1).
        clock: UTC ns, for generation times.

    Raises:
        LinkError: non-positive ``every_s`` or ``valid_s``, or ``risk`` outside [0, 1].
    """

    def __init__(
        self,
        signer: Signer,
        transport: Transport,
        pose: Pose | Callable[[], Pose],
        *,
        every_s: float = 0.5,
        valid_s: float = 2.0,
        risk: float = 1.0,
        epoch_s: float = DEFAULT_EPOCH_S,
        preauth: NonceSource | None = None,
        clock: Callable[[], int] = time.time_ns,
    ) -> None:
        if every_s <= 0 or valid_s <= 0 or not 0.0 <= risk <= 1.0:
            raise LinkError("cue publisher: every_s and valid_s must be > 0, risk in [0, 1]")
        self.signer = signer
        self.transport = transport
        self._pose = pose
        self.every_ns = int(every_s * NS_PER_S)
        self.valid_ns = int(valid_s * NS_PER_S)
        self.risk = risk
        self.epoch_ns = int(epoch_s * NS_PER_S)
        self.preauth = preauth
        self.clock = clock
        self.seq = secrets.randbelow(1 << 32)
        self.stats = CuePublisherStats()
        self._last: dict[int, int] = {}
        self._closed = False

    def on_bearings(self, batch: BearingBatch) -> None:
        """Send a cue for each emitter of ``batch`` not cued in the last ``every_s``."""
        if len(batch) == 0:
            return
        pose = self._pose() if callable(self._pose) else self._pose
        for k in np.argsort(batch.t_ns, kind="stable").tolist():
            emitter = int(batch.emitter[k])
            t_ns = int(batch.t_ns[k])
            last = self._last.get(emitter)
            if last is not None and t_ns - last < self.every_ns:
                self.stats.skipped["rate"] += 1
                continue
            az = float(batch.azimuth_deg[k])
            sigma = float(batch.sigma_deg[k])
            channel = int(batch.channel[k])
            if not (math.isfinite(az) and math.isfinite(sigma) and sigma > 0 and t_ns >= 0):
                self.stats.skipped["invalid"] += 1
                continue
            try:
                band = band_of(channel)
            except LinkError:
                self.stats.skipped["not_wifi"] += 1
                continue
            epoch = t_ns // self.epoch_ns
            cue = Cue(
                sender_id=self.signer.sender_id,
                t_gen_us=self.clock() // 1000,
                seq=self.seq,
                epoch=epoch,
                emitter=emitter,
                t_obs_us=t_ns // 1000,
                valid_until_us=(t_ns + self.valid_ns) // 1000,
                channel=channel,
                band=band,
                phy=Phy.UNKNOWN,
                kind=CueKind.BEARING,
                risk=self.risk,
                x_m=pose.x_m,
                y_m=pose.y_m,
                a=wrap_deg_360(az),
                b=sigma,
            )
            try:
                datagram = sign_cue(self.signer, cue, self._preauth_key(epoch))
                self.transport.send(datagram)
            except LinkError as err:
                self.stats.skipped["send_error"] += 1
                if self.stats.skipped["send_error"] == 1:
                    log.warning("%s; later cue errors are only counted", err)
                continue
            self._last[emitter] = t_ns
            self.seq = (self.seq + 1) % (1 << 32)
            self.stats.cues += 1

    def _preauth_key(self, epoch: int) -> bytes | None:
        if self.preauth is None:
            return None
        try:
            return derive_key(self.preauth.nonce_for(epoch), self.signer.sender_id)
        except NonceUnavailableError:
            return None

    @property
    def name(self) -> str:
        """``send cues URL`` (or the transport's class), for run summaries."""
        endpoint = getattr(self.transport, "endpoint", None)
        url = getattr(endpoint, "url", None)
        return (
            f"send cues {url()}" if callable(url) else f"send cues {type(self.transport).__name__}"
        )
