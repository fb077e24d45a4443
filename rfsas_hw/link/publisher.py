"""Publishing bearings: a bearing-stream listener that sends signed safety messages.

Each batch is split by nonce epoch (a message names one epoch) and then into
chunks that fit the datagram size; every chunk becomes one signed message with
the next sequence number. Sequence numbers start at a random value, so a
restarted sensor does not collide with what receivers remember of its last run.

Only hashed emitter ids reach this stage (a :class:`~rfsas_hw.records.BearingBatch`
cannot hold a raw MAC); nothing here logs bearing contents.
"""

from __future__ import annotations

import logging
import math
import secrets
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from rfsas_hw.angles import wrap_deg_360
from rfsas_hw.errors import KeyStoreError, LinkError
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.message import (
    DEFAULT_DATAGRAM,
    MAX_DATAGRAM,
    VERSION,
    VERSION_PREAUTH,
    Row,
    encode_rows,
    max_bearings,
    row_ok,
    wire_rows,
)
from rfsas_hw.link.preauth import NonceSource, PreauthKeys, sign_datagram
from rfsas_hw.link.signing import Signer
from rfsas_hw.link.transport import Transport, open_transports
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, NS_PER_S
from rfsas_hw.records import BearingBatch, Pose

log = logging.getLogger(__name__)

SNR_UNKNOWN_DB = -999.0
"""SNR sent for a bearing whose unit does not measure one (Doppler, agrelo): the wire
format needs a finite number, and no real SNR is this low."""


@dataclass(slots=True)
class PublisherStats:
    """What a publisher sent and dropped."""

    offered: int = 0
    """Bearings handed to the publisher."""
    messages: int = 0
    bearings: int = 0
    """Bearings sent."""
    bytes: int = 0
    dropped: Counter[str] = field(default_factory=Counter)
    """Bearings not sent, by reason (``invalid`` values, ``send_error``)."""

    def as_dict(self) -> dict[str, int]:
        """Flat counters."""
        out = {"messages": self.messages, "bearings": self.bearings, "bytes": self.bytes}
        out.update({f"dropped.{k}": v for k, v in sorted(self.dropped.items())})
        return out


class Publisher:
    """Signs bearing batches into safety messages and sends them (a ``BearingListener``).

    Args:
        signer: the sensor's signing identity; its id is the sender id on the wire.
        transport: where datagrams go.
        pose: the sensor's pose, or a function returning the current one.
        epoch_s: nonce epoch length, seconds (as the hasher uses).
        max_datagram: largest datagram to build, bytes (≤ 1472).
        clock: UTC time in ns, for generation times.
        first_seq: first sequence number (default: random).
        own_transport: close the transport when the publisher closes.
        preauth: the deployment's epoch nonces; with them, messages are sent as
            version 2, tagged with the sensor's pre-authentication key
            (:mod:`rfsas_hw.link.preauth`); without, as version 1.

    Raises:
        LinkError: ``max_datagram`` is outside what the protocol allows.
    """

    def __init__(
        self,
        signer: Signer,
        transport: Transport,
        pose: Pose | Callable[[], Pose],
        *,
        epoch_s: float = DEFAULT_EPOCH_S,
        max_datagram: int = DEFAULT_DATAGRAM,
        clock: Callable[[], int] = time.time_ns,
        first_seq: int | None = None,
        own_transport: bool = True,
        preauth: NonceSource | None = None,
    ) -> None:
        if not 0 < max_datagram <= MAX_DATAGRAM:
            raise LinkError(f"max datagram {max_datagram} bytes outside 1-{MAX_DATAGRAM}")
        self.signer = signer
        self.transport = transport
        self._pose = pose
        self.epoch_ns = int(epoch_s * NS_PER_S)
        self.preauth = None if preauth is None else PreauthKeys(preauth, keep=16)
        version = VERSION if preauth is None else VERSION_PREAUTH
        self.chunk = max_bearings(signer.sender_id, max_datagram, version)
        self.clock = clock
        self.seq = secrets.randbelow(1 << 32) if first_seq is None else first_seq % (1 << 32)
        self.own_transport = own_transport
        self.stats = PublisherStats()
        self.last_error = ""
        """The last send error, for the summary."""
        self._lost_now: int | None = None
        """Bearings lost since sending last failed (None: the last send went out)."""
        self._closed = False

    @classmethod
    def to_url(
        cls,
        url: str | Sequence[str],
        signer: Signer,
        pose: Pose | Callable[[], Pose],
        *,
        epoch_s: float = DEFAULT_EPOCH_S,
        max_datagram: int = DEFAULT_DATAGRAM,
        clock: Callable[[], int] = time.time_ns,
        preauth: NonceSource | None = None,
    ) -> Publisher:
        """A publisher sending to ``url`` (e.g. ``udp://127.0.0.1:47000``, ``mqtts://…``;
        several URLs: to each of them); it owns the sockets.

        Raises:
            LinkError: bad URL, datagram size, socket or broker failure.
        """
        urls = [url] if isinstance(url, str) else list(url)
        return cls(
            signer,
            open_transports(urls, "send"),
            pose,
            epoch_s=epoch_s,
            max_datagram=max_datagram,
            clock=clock,
            preauth=preauth,
        )

    @classmethod
    def from_keys(
        cls,
        url: str | Sequence[str],
        keys_dir: str | Path,
        pose: Pose | Callable[[], Pose],
        *,
        epoch_s: float = DEFAULT_EPOCH_S,
        max_datagram: int = DEFAULT_DATAGRAM,
        preauth: NonceSource | None = None,
    ) -> Publisher:
        """A publisher signing as the sensor identity in ``keys_dir`` and sending to ``url``.

        Raises:
            KeyStoreError: not a sensor key directory, or its signing key is unusable.
            LinkError: bad URL or socket failure.
        """
        store = KeyStore.open(keys_dir)
        if store.role != "sensor":
            raise KeyStoreError(
                f"{store.path}: a {store.role} identity does not sign bearings; "
                "give a sensor key directory"
            )
        signer = store.signer()
        return cls.to_url(
            url, signer, pose, epoch_s=epoch_s, max_datagram=max_datagram, preauth=preauth
        )

    @property
    def pose(self) -> Pose:
        """The sensor pose that goes into the next message."""
        return self._pose() if callable(self._pose) else self._pose

    def on_bearings(self, batch: BearingBatch) -> None:
        """Send ``batch`` as one or more signed messages; bad rows are dropped and counted.

        A bearing whose unit measured no SNR (NaN) goes with :data:`SNR_UNKNOWN_DB`; one
        with a value the wire cannot carry (:func:`~rfsas_hw.link.message.row_ok`) is
        dropped as ``invalid``. The checks run on the rows as the wire holds them, made
        once and packed as they are (a message holds a few bearings: per-column numpy
        calls cost more than the rows)."""
        n = len(batch)
        if n == 0:
            return
        self.stats.offered += n
        rows = [
            r if r[4] == r[4] else (r[0], r[1], r[2], r[3], SNR_UNKNOWN_DB, r[5])
            for r in wire_rows(batch)
        ]
        if not all(row_ok(r) for r in rows):
            rows = [r for r in rows if row_ok(r)]
            self.stats.dropped["invalid"] += n - len(rows)
            if not rows:
                return
        # the epoch of a bearing as a receiver finds it: from its time on the wire
        epochs = [r[0] * 1000 // self.epoch_ns for r in rows]
        first = epochs[0]
        groups: dict[int, list[Row]] = {first: rows}
        if not all(e == first for e in epochs):
            groups = {}
            for e, r in zip(epochs, rows, strict=True):
                groups.setdefault(e, []).append(r)
        for epoch in sorted(groups):
            part = groups[epoch]
            for start in range(0, len(part), self.chunk):
                self._send(epoch, part[start : start + self.chunk])

    def _send(self, epoch: int, rows: list[Row]) -> None:
        pose = self.pose
        if not all(math.isfinite(v) for v in (pose.x_m, pose.y_m, pose.heading_deg)):
            self.stats.dropped["no_pose"] += len(rows)
            return
        if not 0.0 <= pose.heading_deg < 360.0:
            pose = Pose(pose.x_m, pose.y_m, wrap_deg_360(pose.heading_deg))
        key = None
        if self.preauth is not None:
            key = self.preauth.key_for(self.signer.sender_id, epoch)
            if key is None:
                self.stats.dropped["no_nonce"] += len(rows)
                return
        seq, t_gen_us = self.seq, self.clock() // 1000
        datagram = sign_datagram(
            self.signer,
            self.signer.sender_id,
            "message",
            lambda version: encode_rows(
                self.signer.sender_id, pose, t_gen_us, seq, epoch, rows, version
            ),
            key,
        )
        self.seq = (seq + 1) % (1 << 32)
        try:
            self.transport.send(datagram)
        except LinkError as err:
            self.last_error = str(err)
            self.stats.dropped["send_error"] += len(rows)
            if self._lost_now is None:
                self._lost_now = 0
                log.warning("%s: cannot send (%s); lost bearings are counted", self.name, err)
            self._lost_now += len(rows)
            return
        if self._lost_now is not None:
            log.warning("%s: sending again, %d bearings lost meanwhile", self.name, self._lost_now)
            self._lost_now = None
        self.stats.messages += 1
        self.stats.bearings += len(rows)
        self.stats.bytes += len(datagram)
        if log.isEnabledFor(logging.DEBUG):
            log.debug(
                "sent seq %d: %d bearings, epoch %d, %d bytes",
                seq,
                len(rows),
                epoch,
                len(datagram),
            )

    @property
    def name(self) -> str:
        """``send URL`` (or the transport's class), for run summaries."""
        endpoint = getattr(self.transport, "endpoint", None)
        url = getattr(endpoint, "url", None)
        return f"send {url()}" if callable(url) else f"send {type(self.transport).__name__}"

    def counters(self) -> dict[str, int]:
        """``sent`` bearings, ``messages``, and ``dropped.REASON`` counts."""
        out = {"sent": self.stats.bearings, "messages": self.stats.messages}
        out.update({f"dropped.{k}": v for k, v in sorted(self.stats.dropped.items())})
        return out

    def problem(self) -> str | None:
        """Why the publishing failed, or None: bearings were offered and none were sent,
        or sending still failed at the end. An outage ridden out (sends failed, then
        went out again) is not a failure of the run: its losses are counted
        (``dropped.send_error``) and logged when they start and end."""
        st = self.stats
        if self._lost_now is not None:
            return (
                f"{st.dropped['send_error']:,} bearings not sent, still failing at the end "
                f"({self.last_error})"
            )
        if st.offered and not st.bearings:
            reasons = ", ".join(f"{k} {v:,}" for k, v in sorted(st.dropped.items()))
            return f"none of {st.offered:,} bearings sent ({reasons or 'no reason recorded'})"
        return None

    def close(self) -> None:
        """Close the transport if the publisher owns it; idempotent."""
        if not self._closed:
            self._closed = True
            if self.own_transport:
                self.transport.close()
