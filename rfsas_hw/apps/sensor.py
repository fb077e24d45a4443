"""The sensor application: a source, the pipeline into bearings, and every output.

``rfsas live`` and ``rfsas replay`` are this class plus the mapping of their
flags; from Python::

    from rfsas_hw.apps.sensor import SensorApp, SensorAppConfig

    config = SensorAppConfig(spec="pcap:capture.pcapng", calibration=Path("cal.yaml"),
                             out=Path("bearings.jsonl"))
    with SensorApp(config) as app:
        summary = app.run()

A source that gives bearings itself (a DF unit: ``agrelo:``, ``kraken:``)
runs without a pipeline; one that names its transmitters hashes them with
the deployment's epoch nonces, as the pipeline does for frames.
"""

from __future__ import annotations

import os
import weakref
from collections.abc import Iterable, Mapping
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import rfsas_hw.sources
from rfsas_hw.apps.ros2 import Ros2Options, sensor_scene
from rfsas_hw.closing import ClosingContext
from rfsas_hw.df import load_calibration
from rfsas_hw.df.fovguard import FovGuard
from rfsas_hw.errors import ConfigError
from rfsas_hw.fleet.certname import check_certificate_names
from rfsas_hw.link.cue_publisher import CuePublisher
from rfsas_hw.link.cue_receiver import CueInbox, CueReceiver
from rfsas_hw.link.distribution import NonceInbox
from rfsas_hw.link.fallback import FallbackSender
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.preauth import NonceSource
from rfsas_hw.link.publisher import Publisher
from rfsas_hw.link.transport import open_transport, open_transports
from rfsas_hw.outpaths import check_output
from rfsas_hw.output import BearingWriter
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, DEFAULT_GRACE_S, EpochSchedule
from rfsas_hw.privacy.hashing import DerivedNonces, FixedNonce, MacHasher, NonceProvider
from rfsas_hw.records import Pose
from rfsas_hw.runner import ProgressFn, Runner, RunSummary
from rfsas_hw.sources.registry import parse_spec, source_class
from rfsas_hw.sources.schedule import NoteHeard
from rfsas_hw.stream import Fanout


@dataclass(frozen=True, slots=True)
class SensorAppConfig:
    """Everything the sensor application is built from."""

    spec: str
    """The source: ``scheme:argument`` (``pcap:capture.pcap``, ``wifi:wlan0mon``, …)."""
    source_options: Mapping[str, Any] = field(default_factory=dict)
    """Options of the source's driver (``errors``, ``n_antennas``, ``channels`` …)."""
    calibration: Path | None = None
    """Calibration YAML of the antenna pair (needed unless the source gives bearings)."""
    sensor_id: str = "sensor-1"
    """Id in the bearings."""
    pose: Pose = field(default_factory=lambda: Pose(0.0, 0.0, 0.0))
    """Sensor position (metres east, north) and boresight (compass degrees)."""
    min_snr_db: float | None = None
    """Reject frames whose stronger antenna is below this SNR, dB."""
    moving_mount: bool = False
    """The sensor moves (a vehicle, a robot): no motion rule by default (an emitter on a
    collision course keeps its bearing). See :meth:`~rfsas_hw.df.fovguard.FovGuard.for_mount`."""
    prove_motion_deg: float | None = None
    """An emitter's bearings count once its bearing has swept this far, degrees (static
    emitters never count; 0: at once; None: the mount's default,
    :data:`~rfsas_hw.df.fovguard.PROVE_MOTION_DEG` on a fixed mount, 0 on a moving one).
    See :class:`~rfsas_hw.df.fovguard.FovGuard`."""
    epoch_s: float = DEFAULT_EPOCH_S
    """Nonce epoch length of the deployment, seconds."""
    nonce_secret: Path | None = None
    """Derive epoch nonces from this shared secret file (None: see ``nonces``)."""
    nonces: str | None = None
    """Receive the deployment's epoch nonces here from the authority (needs ``keys_dir``;
    None with no ``nonce_secret``: a random key for this run)."""
    keys_dir: Path | None = None
    """The sensor's key directory: signs what is sent, opens the nonce envelopes."""
    out: Path | None = None
    """Write bearings here (``.jsonl``, ``.csv``, ``.mcap``; ``-``: standard output)."""
    fmt: str | None = None
    """Output format (default: from the name of ``out``)."""
    force: bool = False
    """Replace an existing ``out`` file (never an input)."""
    inputs: tuple[str | Path, ...] = ()
    """Files the run reads: ``out`` never replaces one of them."""
    send: tuple[str, ...] = ()
    """Publish bearings as signed safety messages to these URLs."""
    fallback: str | None = None
    """Out-of-band path for ``send``."""
    send_cues: str | None = None
    """Also send signed cues for the bearings here."""
    cues: str | None = None
    """Obey signed cues arriving here (a hopping ``wifi:`` source; needs ``keys_dir``)."""
    ros2: Ros2Options = field(default_factory=Ros2Options)
    """Live ROS 2 outputs (Foxglove, DDS)."""
    duration_s: float | None = None
    """Stop after this many seconds (None: at the end of the input)."""
    realtime: bool = False
    """Pace recorded frames at their recorded times."""
    speed: float = 1.0
    """Pace factor with ``realtime`` (2 = twice as fast)."""
    retime: bool = False
    """Give frames the time they are replayed at (with ``realtime``)."""


def epoch_schedule(epoch_s: float) -> EpochSchedule:
    """The deployment's epochs for ``epoch_s`` (default grace period, capped below half
    an epoch for short test epochs).

    Raises:
        ConfigError: the epoch length is not usable.
    """
    try:
        return EpochSchedule(epoch_s, min(5.0, epoch_s / 4))
    except ValueError as err:
        raise ConfigError(f"--epoch: {err}") from err


def build_pipeline(
    calibration_path: Path | None,
    sensor_id: str,
    pose: Pose,
    min_snr_db: float | None,
    nonces: NonceProvider | None = None,
    nonce_secret: Path | None = None,
    epoch_s: float = DEFAULT_EPOCH_S,
    prove_motion_deg: float | None = None,
    moving_mount: bool = False,
) -> SensorPipeline:
    """The pipeline hashing with ``nonces`` (the deployment's epoch nonces), with
    nonces derived from the secret in ``nonce_secret``, or by default with a
    per-run random key (ids unlinkable across runs); its field-of-view guard is the
    one for the mount (``moving_mount``, ``prove_motion_deg``: see
    :meth:`FovGuard.for_mount`).

    Raises:
        CalibrationError / ConfigError: the calibration file is unusable.
        KeyStoreError: the secret file is unreadable, too short or not private.
    """
    if nonces is not None and nonce_secret is not None:
        raise ConfigError("give --nonces or --nonce-secret, not both")
    if calibration_path is None:
        raise ConfigError("--calibration CAL.yaml is required to turn RSSI pairs into bearings")
    calibration = load_calibration(calibration_path)
    if nonce_secret is not None:
        nonces = DerivedNonces.from_file(nonce_secret)
    hasher = MacHasher(nonces if nonces is not None else FixedNonce(os.urandom(32)), epoch_s)
    guard = FovGuard.for_mount(moving_mount, prove_motion_deg)
    return SensorPipeline(
        calibration, hasher, sensor_id, pose, min_snr_db=min_snr_db, fov_guard=guard
    )


def deployment_nonces(pipeline: SensorPipeline | None) -> NonceProvider | None:
    """The deployment's epoch nonces the pipeline hashes with (from the authority or a
    shared secret), which also pre-authenticate what is sent (version-2 messages);
    None for a per-run random key, which no receiver holds."""
    if pipeline is None or isinstance(pipeline.hasher.nonces, FixedNonce):
        return None
    return pipeline.hasher.nonces


def open_publisher(
    send: Iterable[str],
    keys_dir: Path | None,
    pose: Pose,
    epoch_s: float = DEFAULT_EPOCH_S,
    preauth: NonceSource | None = None,
    fallback: str | None = None,
) -> Publisher | None:
    """A publisher of signed bearings to every URL in ``send`` (None: no URL), through a
    :class:`~rfsas_hw.link.fallback.FallbackSender` when a ``fallback`` URL is given;
    with the deployment's epoch nonces in ``preauth`` it sends version-2 messages.

    Raises:
        ConfigError: URLs without ``keys_dir``, or a ``fallback`` without URLs.
        KeyStoreError: the key directory is not a usable sensor identity.
        LinkError: bad URL or socket failure.
    """
    urls = list(send)
    if not urls:
        if fallback is not None:
            raise ConfigError("--fallback is the out-of-band path of --send: give --send too")
        return None
    if keys_dir is None:
        raise ConfigError("--send needs --keys DIR: messages are signed with the sensor's key")
    store = KeyStore.open(keys_dir)
    check_certificate_names(urls, store.id, "--send")
    check_certificate_names([fallback] if fallback else [], store.id, "--fallback")
    if fallback is None:
        return Publisher.from_keys(urls, keys_dir, pose, epoch_s=epoch_s, preauth=preauth)
    signer = store.signer()
    primary = open_transports(urls, "send")
    try:
        secondary = open_transport(fallback, "send")
    except BaseException:
        primary.close()
        raise
    return Publisher(
        signer, FallbackSender(primary, secondary), pose, epoch_s=epoch_s, preauth=preauth
    )


def open_cue_publisher(
    url: str | None, keys_dir: Path | None, pose: Pose, epoch_s: float = DEFAULT_EPOCH_S
) -> CuePublisher | None:
    """A publisher of signed cues for the bearings to ``url`` (None: no cues).

    Raises:
        ConfigError: a URL without ``keys_dir``.
        KeyStoreError: the key directory is not a usable sensor identity.
        LinkError: bad URL or socket failure.
    """
    if url is None:
        return None
    if keys_dir is None:
        raise ConfigError("--send-cues needs --keys DIR: cues are signed with the sensor's key")
    store = KeyStore.open(keys_dir)
    check_certificate_names([url], store.id, "--send-cues")
    signer = store.signer()
    return CuePublisher(signer, open_transport(url, "send"), pose, epoch_s=epoch_s)


def open_nonce_inbox(
    url: str,
    keys_dir: Path | None,
    epoch_s: float = DEFAULT_EPOCH_S,
    grace_s: float = DEFAULT_GRACE_S,
    wait_s: float = 10.0,
) -> NonceInbox:
    """A nonce provider listening at ``url`` for the authority's envelopes (sealed to the
    key in ``keys_dir``), waiting up to ``wait_s`` for a missing epoch's nonce.

    Raises:
        ConfigError: no ``keys_dir``.
        KeyStoreError: the key directory has no enrolled authority or no usable key.
        LinkError: bad URL or socket failure.
    """
    if keys_dir is None:
        raise ConfigError("--nonces needs --keys DIR: envelopes are sealed to the sensor's key")
    keys = KeyStore.open(keys_dir)
    check_certificate_names([url], keys.id, "--nonces")
    store = keys.nonce_store(EpochSchedule(epoch_s, grace_s))
    inbox = NonceInbox(store, open_transport(url, "recv"), wait_s=wait_s)
    # whoever holds the inbox keeps it for the whole run; close the socket when it goes
    weakref.finalize(inbox, inbox.transport.close)
    return inbox


class SensorApp(ClosingContext):
    """The sensor assembled from a :class:`SensorAppConfig`: the source is open and
    every output started when the constructor returns. :meth:`run` runs it once and
    closes the source and the outputs; :meth:`close` does so without running.

    Raises (from the constructor):
        ConfigError: no output at all, a bad output name, an output that is an input,
            an existing output without ``force``, or options that need others.
        CalibrationError: the calibration is unusable.
        KeyStoreError / LinkError: sending or receiving nonces cannot be set up.
        SourceError: the source cannot be opened.
    """

    def __init__(self, config: SensorAppConfig) -> None:
        self.config = config
        self.notes: list[str] = []
        """What to tell the user about the outputs started (URLs, topics)."""
        schedule = epoch_schedule(config.epoch_s)
        scheme, _ = parse_spec(config.spec)
        cls = source_class(scheme)
        options = dict(config.source_options)
        self.pipeline: SensorPipeline | None = None
        if not cls.yields_bearings:
            self.pipeline = self._pipeline(schedule)
        elif getattr(cls, "hashes_ids", False):
            # the unit names its transmitters (BLE tag addresses): the source hashes
            # them with the deployment's epoch nonces, as the pipeline does for frames
            if config.nonces is not None and config.nonce_secret is not None:
                raise ConfigError("give --nonces or --nonce-secret, not both")
            if config.nonces is not None:
                inbox = self._inbox(config.nonces, schedule)
                options["hasher"] = MacHasher(inbox, config.epoch_s)
            elif config.nonce_secret is not None:
                nonces = DerivedNonces.from_file(config.nonce_secret)
                options["hasher"] = MacHasher(nonces, config.epoch_s)
        if config.cues is not None and ("channels" not in options or config.keys_dir is None):
            raise ConfigError("--cues needs --channels (the plan cues interrupt) and --keys")
        self.source = rfsas_hw.sources.open(config.spec, **options)
        with ExitStack() as stack:
            stack.callback(self.source.close)
            self.listeners = self._listeners()
            stack.callback(self.listeners.close)
            self._obey_cues()
            self.runner = Runner(
                self.source,
                self.pipeline,
                self.listeners,
                realtime=config.realtime or config.retime,
                speed=config.speed,
                retime=config.retime,
                duration_s=config.duration_s,
            )
            stack.pop_all()
        self._closed = False

    def _inbox(self, url: str, schedule: EpochSchedule) -> NonceInbox:
        """The authority's nonces arriving at ``url``."""
        # no waiting inside the hasher: frames without a nonce yet wait in the
        # pipeline's hold queue, and the sensor keeps reading
        keys = self.config.keys_dir
        return open_nonce_inbox(url, keys, schedule.epoch_s, schedule.grace_s, wait_s=0.0)

    def _pipeline(self, schedule: EpochSchedule) -> SensorPipeline:
        cfg = self.config
        inbox = self._inbox(cfg.nonces, schedule) if cfg.nonces is not None else None
        pipeline = build_pipeline(
            cfg.calibration,
            cfg.sensor_id,
            cfg.pose,
            cfg.min_snr_db,
            inbox,
            nonce_secret=cfg.nonce_secret,
            epoch_s=cfg.epoch_s,
            prove_motion_deg=cfg.prove_motion_deg,
            moving_mount=cfg.moving_mount,
        )
        if inbox is not None:
            pipeline.end_wait_s = 10.0  # a short input may end before the first envelope
        return pipeline

    def _listeners(self) -> Fanout:
        """Every output the configuration asks for, in one fan-out."""
        cfg = self.config
        if cfg.out is None and not cfg.send and not cfg.ros2.wants_live:
            raise ConfigError("nothing to do: give --out FILE and/or --send URL")
        if cfg.out is not None:
            check_output(cfg.out, cfg.inputs, force=cfg.force, what="--out")
        fanout = Fanout()
        with ExitStack() as stack:
            stack.callback(fanout.close)
            preauth = deployment_nonces(self.pipeline)
            publisher = open_publisher(
                cfg.send, cfg.keys_dir, cfg.pose, cfg.epoch_s, preauth, cfg.fallback
            )
            if publisher is not None:
                stack.callback(publisher.close)
            cue_publisher = open_cue_publisher(cfg.send_cues, cfg.keys_dir, cfg.pose, cfg.epoch_s)
            if cue_publisher is not None:
                stack.callback(cue_publisher.close)
            if cfg.out is not None:
                from rfsas_hw.ros2.outputs import sensor_recording

                pose = cfg.pose
                recording = sensor_recording(cfg.out, cfg.fmt, lambda _sensor_id: pose)
                fanout.add(recording if recording is not None else BearingWriter(cfg.out, cfg.fmt))
            for listener in (publisher, cue_publisher):
                if listener is not None:
                    fanout.add(listener)
            scene, lines = sensor_scene(cfg.ros2, lambda _sensor_id: cfg.pose)
            if scene is not None:
                fanout.add(scene)
                self.notes += lines
            stack.pop_all()
        return fanout

    def _obey_cues(self) -> None:
        """Let the source's channel scheduler (a hopping source) obey cues from ``cues``."""
        cfg = self.config
        scheduler = getattr(self.source, "scheduler", None)
        if cfg.cues is None or scheduler is None or cfg.keys_dir is None:
            return
        trust = KeyStore.open(cfg.keys_dir).trust
        scheduler.inbox = CueInbox(CueReceiver(trust, transport=open_transport(cfg.cues, "recv")))
        self.listeners.add(NoteHeard(scheduler, self.source.now_s))  # type: ignore[attr-defined]

    def run(self, progress: ProgressFn | None = None) -> RunSummary:
        """Read the source to its end, ``duration_s`` or Ctrl-C/SIGTERM, through the
        pipeline into every output; the source and the outputs are closed after.

        Args:
            progress: called after each batch with the bytes read and the total.
        """
        if self._closed:
            raise ConfigError("a sensor application runs once")
        self._closed = True  # the runner closes the source and the outputs
        if progress is not None:
            self.runner.progress = progress
        return self.runner.run()

    def stop(self) -> None:
        """Ask a running :meth:`run` to end (from another thread)."""
        self.runner.stop()

    def close(self) -> None:
        """Close the source and the outputs without running. Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self.source.close()
        finally:
            self.listeners.close()
