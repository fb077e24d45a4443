"""The backend application: receiver, service, vehicle feed, result sinks, dashboard.

``rfsas backend`` is this class plus the mapping of its flags; from Python::

    from rfsas_hw.apps.backend import BackendApp, BackendAppConfig

    config = BackendAppConfig(listen=("udp://127.0.0.1:47000",), keys_dir=Path("keys/obu-1"),
                              out=Path("run.jsonl"), duration_s=60.0)
    with BackendApp(config) as app:
        app.run()
    print(app.stats())

The service's settings come from three places, applied once, in
:func:`resolve_settings`: the defaults (or a :class:`BackendConfig` given in
Python), then the settings file, then the overrides (the command's flags).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from rfsas_hw.apps.ros2 import Ros2Options, Ros2Outputs, attach_scene
from rfsas_hw.backend.service import (
    BackendConfig,
    BackendService,
    JsonlSink,
    ResultSink,
    load_backend_config,
)
from rfsas_hw.backend.vehicle import VehicleFeed, VehicleState, load_vehicle
from rfsas_hw.closing import ClosingContext
from rfsas_hw.errors import ConfigError
from rfsas_hw.fleet.certname import check_certificate_names
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link import Receiver, ReceiverConfig, open_transport
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.transport import Transport
from rfsas_hw.optional import require
from rfsas_hw.outpaths import check_output
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.records import Assessment


@dataclass(frozen=True, slots=True)
class SettingsOverrides:
    """Settings that replace those of the settings file (None: keep the file's)."""

    window_s: float | None = None
    """Association window (``association.window_s``), seconds."""
    epoch_s: float | None = None
    """Nonce epoch length of the deployment (``association.epoch_s``), seconds."""
    threat_kind: str | None = None
    """What the emitters are carried by (``encounter.threat_kind``)."""
    reaction_s: float | None = None
    """Reaction delay before braking (``encounter.reaction_s``), seconds."""
    origin: SiteOrigin | None = None
    """Site origin on WGS-84 (``site.origin``)."""
    site_map: Path | None = None
    """Buildings and roads for the dashboard (``site.map``)."""


_OVERRIDDEN: dict[str, tuple[str, str]] = {
    "window_s": ("association", "window_s"),
    "epoch_s": ("association", "epoch_s"),
    "threat_kind": ("encounter", "threat_kind"),
    "reaction_s": ("encounter", "reaction_s"),
    "origin": ("site", "origin"),
    "site_map": ("site", "map"),
}
"""Where each override goes: (section of :class:`BackendConfig`, field of the section)."""


def resolve_settings(
    base: BackendConfig,
    settings_file: Path | None = None,
    overrides: SettingsOverrides | None = None,
) -> BackendConfig:
    """The service's settings: ``base``, replaced by ``settings_file`` when given, then
    by every override in ``overrides`` that is not None.

    Raises:
        ConfigError: the settings file is unreadable or has a bad key or value.
        BackendError / ValueError: an override makes a section invalid (e.g. a window
            not shorter than the epoch); the message says which values clash.
    """
    config = base if settings_file is None else load_backend_config(settings_file)
    overrides = overrides or SettingsOverrides()
    changes: dict[str, dict[str, Any]] = {}
    for name, (section, key) in _OVERRIDDEN.items():
        value = getattr(overrides, name)
        if value is not None:
            changes.setdefault(section, {})[key] = value
    sections = {name: replace(getattr(config, name), **kv) for name, kv in changes.items()}
    return replace(config, **sections)


@dataclass(frozen=True, slots=True)
class BackendAppConfig:
    """Everything the backend application is built from."""

    listen: tuple[str, ...]
    """Where signed safety messages arrive: ``udp://HOST:PORT`` or broker URLs."""
    keys_dir: Path
    """The backend's key directory; its ``trust/`` holds the enrolled sensors' cards."""
    settings: BackendConfig = field(default_factory=BackendConfig)
    """Settings of the service when there is no ``settings_file``."""
    settings_file: Path | None = None
    """Settings of the service in YAML (replaces ``settings``)."""
    overrides: SettingsOverrides = field(default_factory=SettingsOverrides)
    """Settings that replace the file's."""
    vehicle: str | None = None
    """Vehicle state: a YAML/JSON file, or ``udp://HOST:PORT`` receiving JSON states."""
    vehicle_id: str = ""
    """Id of the vehicle judged against (its advisory topic)."""
    out: Path | None = None
    """Write every fix and assessment as JSON lines (``.mcap``: an MCAP recording)."""
    plot: Path | None = None
    """Where :meth:`BackendApp.draw_map` draws the map PNG."""
    duration_s: float | None = None
    """How long :meth:`BackendApp.run` runs, seconds (None: until stopped)."""
    web: str | None = None
    """Serve the live dashboard at ``[HOST:]PORT`` (None: no dashboard)."""
    web_token: str | None = None
    """Token other hosts must give the dashboard (None: random when not on loopback)."""
    cot: str | None = None
    """Send Cursor-on-Target events to this TAK server (needs the site origin)."""
    cpm: str | None = None
    """Send the tracks as ETSI Collective Perception Messages to this URL (needs the site
    origin and the v2x extra)."""
    cpm_station_id: int = 1
    """StationId of this backend in its CPMs."""
    cpm_from_vehicle: bool = False
    """The CPMs come from the vehicle (its position their reference, its heading their
    orientation) rather than from a roadside unit at the site origin."""
    advise: str | None = None
    """Publish signed assessments to this broker (needs the site origin)."""
    send_cues: str | None = None
    """Send signed fix cues for emitters at risk to this URL."""
    cues_fallback: str | None = None
    """Out-of-band path for ``send_cues`` while the link's latency watch is in alarm."""
    tile_plan: Path | None = None
    """Tile plan: broker ``listen`` URLs take the tiles of this backend's group."""
    prior_file: Path | None = None
    """RF activity prior file, counted with this run's fixes and written back at the end."""
    accept_v1: bool = False
    """Also accept version-1 messages while a nonce authority is enrolled (a fleet still
    migrating). Without an enrolled authority version 1 is the only kind that can be
    checked and is always accepted."""
    ros2: Ros2Options = field(default_factory=Ros2Options)
    """ROS 2 outputs (bag, Foxglove, DDS, odometry as vehicle state)."""


class BackendApp(ClosingContext):
    """The backend assembled from a :class:`BackendAppConfig`: every socket is open and
    every output started when the constructor returns; :meth:`close` ends them all.

    Raises (from the constructor):
        ConfigError: unusable settings, an output that would overwrite an input, an
            option that needs another (``cot`` without the site origin …), or a key
            directory with no enrolled sensors.
        KeyStoreError: the key directory is not usable.
        LinkError: a URL is bad or a socket cannot be bound.
        MissingDependencyError: an output's optional dependency is not installed (checked
            before anything is bound, for the map too, which is drawn after the run).
    """

    def __init__(
        self, config: BackendAppConfig, *, clock: Callable[[], int] = time.time_ns
    ) -> None:
        self.config = config
        self.clock = clock
        """UTC ns the receiver checks message ages with and the service steps on (the wall
        clock; a simulation run slower than real time gives its own)."""
        self.settings = self._checked_settings()
        self.store = KeyStore.open(config.keys_dir)
        check_certificate_names(
            [u for u in (config.advise, config.send_cues) if u],
            self.store.id,
            "--advise/--send-cues",
        )
        if len(self.store.trust) == 0:
            raise ConfigError(
                f"{config.keys_dir}: no enrolled sensors in trust/ (rfsas keys enroll)"
            )
        vehicle = self._vehicle()
        self.cpm_sink: Any = None
        self.senders: dict[str, Any] = {}
        """The signed-message senders by stats prefix (``advisories``, ``cues``): their
        ``counters()`` (sent, failed, refused, dropped.*) are in :meth:`stats`."""
        """The CPM sender (its ``counters()``), or None."""
        self.notes: list[str] = []
        """What to tell the user about the outputs started (URLs, topics)."""
        with ExitStack() as stack:
            self.receiver = self._open_receiver()
            stack.callback(self.receiver.close)
            self.vehicle_feed: Any = None
            """Where vehicle states arrive (a UDP feed or an odometry topic), or None."""
            if config.vehicle is not None and config.vehicle.startswith("udp://"):
                feed = VehicleFeed.listen(config.vehicle)
                stack.callback(feed.close)
                self.vehicle_feed = feed
            with ExitStack() as sink_stack:
                sinks = self._open_sinks(sink_stack)
                self.service = BackendService(
                    self.settings, vehicle=vehicle, sinks=sinks, clock=self.clock
                )
                sink_stack.pop_all()  # the service closes its sinks from now on
            stack.callback(self.service.close)
            if self.cpm_sink is not None and config.cpm_from_vehicle:
                service = self.service
                self.cpm_sink.vehicle = lambda: service.vehicle
            self.service.link_stats = self.receiver.counters
            ros2_out: Ros2Outputs = attach_scene(self.service, config.out, config.ros2)
            stack.callback(ros2_out.close)
            self.notes += ros2_out.lines
            self.vehicle_feed = self.vehicle_feed or ros2_out.vehicle_feed
            self.dashboard_url: str | None = None
            """Where the dashboard is served, or None."""
            if config.web is not None:
                from rfsas_hw.web import start_dashboard

                dashboard = start_dashboard(
                    self.service,
                    config.web,
                    latency=self.receiver.latency,
                    token=config.web_token,
                )
                stack.callback(dashboard.stop)
                self.dashboard_url = dashboard.url
                self.notes.append(f"dashboard at {dashboard.url}")
            self._closing = stack.pop_all()

    def _checked_settings(self) -> BackendConfig:
        """The service's settings, once the outputs, the optional dependencies and the
        options that need each other are checked (nothing is opened yet)."""
        config = self.config
        inputs = [p for p in (config.settings_file, config.overrides.site_map) if p is not None]
        if config.vehicle is not None:
            inputs.append(Path(config.vehicle))
        for target in (config.out, config.plot):
            if target is not None:  # an existing result is replaced: it is this run's output
                check_output(target, [*inputs, *config.keys_dir.glob("**/*")], force=True)
        if config.plot is not None:
            require("matplotlib")  # before the run, not at its end
        settings = resolve_settings(config.settings, config.settings_file, config.overrides)
        origin = settings.site.origin
        if config.cot is not None and origin is None:
            raise ConfigError("--cot needs the site origin: --origin LAT,LON or site.origin")
        if config.cpm is not None and origin is None:
            raise ConfigError("--cpm needs the site origin: --origin LAT,LON or site.origin")
        if config.advise is not None and origin is None:
            raise ConfigError("--advise needs the site origin: --origin LAT,LON or site.origin")
        if config.cues_fallback is not None and config.send_cues is None:
            raise ConfigError("--cues-fallback is the out-of-band path of --send-cues")
        return settings

    @property
    def enrolled(self) -> int:
        """How many sensors are enrolled in the key directory's trust."""
        return len(self.store.trust)

    def _open_receiver(self) -> Receiver:
        epoch = self.settings.association.epoch_s
        trust = self.store.trust
        urls = list(self.config.listen)
        if self.config.tile_plan is not None:
            from rfsas_hw.fleet.tiles import load_tile_plan, with_tiles

            plan = load_tile_plan(self.config.tile_plan)
            urls = [with_tiles(u, plan, self.store.id) for u in urls]
        check_certificate_names(urls, self.store.id, "--listen")
        grace_s = min(5.0, epoch / 4)
        return Receiver.listen(
            urls,
            trust,
            # with an authority enrolled, envelopes arriving on the link (a broker's
            # retained nonce topic) give the keys that pre-authenticate version-2 messages
            self.store.nonce_store(EpochSchedule(epoch, grace_s), self.clock)
            if trust.authorities()
            else None,
            config=ReceiverConfig(
                epoch_s=epoch,
                grace_s=grace_s,
                # with an authority every sensor can send version 2: require it by default
                accept_v1=self.config.accept_v1 or not trust.authorities(),
            ),
            clock=self.clock,
        )

    def _vehicle(self) -> VehicleState | None:
        vehicle = self.config.vehicle
        return None if vehicle is None or vehicle.startswith("udp://") else load_vehicle(vehicle)

    def _open_sinks(self, stack: ExitStack) -> list[ResultSink]:
        """The result sinks the configuration asks for; each is closed by ``stack``."""
        cfg, origin = self.config, self.settings.site.origin
        epoch = self.settings.association.epoch_s
        sinks: list[ResultSink] = []

        def add(sink: ResultSink) -> None:
            stack.callback(sink.close)
            sinks.append(sink)

        if cfg.out is not None and cfg.out.suffix.lower() != ".mcap":
            add(JsonlSink(cfg.out, origin=origin, bearings=True))
        if cfg.prior_file is not None:
            from rfsas_hw.backend.prior import PriorSink

            add(PriorSink(cfg.prior_file))
        if cfg.cot is not None and origin is not None:
            from rfsas_hw.exports.tak import CotSender

            add(CotSender(cfg.cot, origin))
        if cfg.cpm is not None:
            from rfsas_hw.v2x.sink import backend_cpm_sink

            self.cpm_sink = backend_cpm_sink(
                cfg.cpm,
                cfg.cpm_station_id,
                self.settings.site,
                vehicle_station=cfg.cpm_from_vehicle,
            )
            add(self.cpm_sink)
        if cfg.advise is not None and origin is not None:
            from rfsas_hw.fleet.advisory import AdvisorySink

            signer = self.store.signer()
            self.senders["advisories"] = AdvisorySink.to_url(
                cfg.advise, signer, origin, vehicle_id=cfg.vehicle_id, epoch_s=epoch
            )
            add(self.senders["advisories"])
        if cfg.send_cues is not None:
            from rfsas_hw.backend.cuer import BackendCuer

            link = self._cue_link(cfg.send_cues, cfg.cues_fallback)
            self.senders["cues"] = BackendCuer(self.store.signer(), link, epoch_s=epoch)
            add(self.senders["cues"])
        return sinks

    def _cue_link(self, url: str, fallback: str | None) -> Transport:
        """Where cues go: ``url``, moving to ``fallback`` while the link is late."""
        link: Transport = open_transport(url, "send")
        if fallback is None:
            return link
        from rfsas_hw.link.fallback import FallbackSender

        with ExitStack() as guard:
            guard.callback(link.close)
            secondary = open_transport(fallback, "send")
            guard.pop_all()
        receiver = self.receiver
        # a jammed channel is jammed both ways: what arrives late here says what we
        # send on the same channel arrives late too
        return FallbackSender(link, secondary, alarm=lambda: receiver.latency.alarm)

    def run(
        self,
        on_step: Callable[[list[Assessment]], None] | None = None,
        should_stop: Callable[[], bool] | None = None,
    ) -> None:
        """Receive, locate and judge for ``duration_s`` of the configuration, until
        ``should_stop()`` is true, or until interrupted (KeyboardInterrupt propagates).

        Args:
            on_step: called with each step's assessments (e.g. to redraw a table).
            should_stop: polled between receives; True ends the run.
        """
        self.service.run(
            self.receiver,
            duration_s=self.config.duration_s,
            vehicle_feed=self.vehicle_feed,
            on_step=on_step,
            should_stop=should_stop,
        )

    def stats(self) -> dict[str, int]:
        """The service's and the link's counters (``link.`` prefixed) and what the
        advisory and cue senders sent, failed to send or had refused (``advisories.``,
        ``cues.`` prefixed), flat."""
        out = self.service.all_stats()
        for prefix, sender in self.senders.items():
            out.update({f"{prefix}.{k}": v for k, v in sender.counters().items()})
        return out

    def draw_map(self) -> Path | None:
        """Draw the map PNG with 2σ covariance ellipses to ``plot`` of the configuration
        and return its path (None: no ``plot`` configured).

        Raises:
            MissingDependencyError: matplotlib (the plot extra) is not installed.
        """
        if self.config.plot is None:
            return None
        from rfsas_hw.backend.plot import plot_map

        plot_map(
            self.config.plot,
            stations=self.service.stations,
            assessments=self.service.assessments.values(),
            fixes=self.service.fixes.values(),
            vehicle=self.service.vehicle,
        )
        return self.config.plot

    def close(self) -> None:
        """Stop the dashboard and ROS 2 outputs, close the sinks (the JSON lines file
        gets its stats line), the vehicle feed and the receiver. Idempotent."""
        self._closing.close()
