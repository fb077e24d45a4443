"""``rfsas live``: bearings from a live source (monitor-mode Wi-Fi, a pcap stream, a DF board)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click
from rich.console import Console

import rfsas_hw.sources
from rfsas_hw.cli.linkopts import NONCES_HELP, nonce_inbox
from rfsas_hw.cli.ros2opts import live_options
from rfsas_hw.cli.sensoropts import (
    build_listeners,
    build_pipeline,
    deployment_nonces,
    epoch_schedule,
    finish_run,
    parse_pose,
    sensor_options,
)
from rfsas_hw.errors import ConfigError
from rfsas_hw.link.cue_receiver import CueInbox, CueReceiver
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.transport import open_transport
from rfsas_hw.privacy.hashing import DerivedNonces, MacHasher
from rfsas_hw.runner import Runner
from rfsas_hw.sources.registry import parse_spec, source_class
from rfsas_hw.sources.schedule import NoteHeard, SchedulerConfig


def parse_channels(text: str) -> list[int]:
    """``"1,6,11"`` to channel numbers.

    Raises:
        ConfigError: not a comma-separated list of positive integers.
    """
    try:
        channels = [int(part) for part in text.split(",") if part.strip()]
    except ValueError as err:
        raise ConfigError(f"--channels {text!r}: expected numbers like 1,6,11") from err
    if not channels or any(c <= 0 for c in channels):
        raise ConfigError(f"--channels {text!r}: expected positive channel numbers")
    return channels


@click.command()
@click.argument("spec")
@sensor_options
@live_options
@click.option("--nonces", metavar="udp://HOST:PORT", help=NONCES_HELP)
@click.option(
    "--duration",
    type=click.FloatRange(min=0, min_open=True),
    help="Stop after this many seconds.",
)
@click.option(
    "--channels",
    help="Hop over these channels (wifi: sources; a serial: board's scan plan), e.g. 1,6,11.",
)
@click.option(
    "--dwell",
    type=click.FloatRange(min=0, min_open=True),
    default=0.2,
    show_default=True,
    help="Seconds on each channel when hopping.",
)
@click.option(
    "--any-link-type",
    is_flag=True,
    help="wifi: accept an interface that is not radiotap (ARPHRD 803); for tests on veth pairs.",
)
@click.option(
    "--cues",
    metavar="URL",
    help="Obey signed cues arriving here (roadside units, the backend; senders enrolled "
    "in --keys): dwell on the cued channel, then resume --channels.",
)
def live(
    spec: str,
    calibration_path: Path | None,
    out: Path | None,
    force: bool,
    json_summary: bool,
    epoch_s: float,
    fmt: str | None,
    sensor_id: str,
    pose: str,
    origin: str | None,
    min_snr_db: float | None,
    nonce_secret: Path | None,
    errors: str,
    send: str | None,
    keys_dir: Path | None,
    nonces: str | None,
    duration: float | None,
    channels: str | None,
    dwell: float,
    any_link_type: bool,
    cues: str | None,
    **ros2: Any,
) -> None:
    """Run the sensor on SPEC until Ctrl-C, the end of the input, or --duration.

    \b
    rfsas live wifi:wlan0mon --calibration cal.yaml --out bearings.jsonl
    rfsas live wifi:wlan0mon --channels 1,6,11 --dwell 0.2 --calibration cal.yaml --out b.csv
    tcpdump -i wlan0mon -w - | rfsas live pcap:- --calibration cal.yaml --out b.jsonl
    """
    console = Console(stderr=True)
    where = parse_pose(pose, origin)
    scheme, _ = parse_spec(spec)
    pipeline = None
    schedule = epoch_schedule(epoch_s)
    if not source_class(scheme).yields_bearings:
        # no waiting inside the hasher: frames without a nonce yet wait in the
        # pipeline's hold queue, and the sensor keeps reading
        inbox = (
            nonce_inbox(nonces, keys_dir, schedule.epoch_s, schedule.grace_s, wait_s=0.0)
            if nonces is not None
            else None
        )
        pipeline = build_pipeline(
            calibration_path,
            sensor_id,
            where,
            min_snr_db,
            inbox,
            nonce_secret=nonce_secret,
            epoch_s=epoch_s,
        )
        if inbox is not None:
            pipeline.end_wait_s = 10.0  # a short input may end before the first envelope
    options: dict[str, Any] = {"errors": errors}
    if pipeline is None and getattr(source_class(scheme), "hashes_ids", False):
        # the unit names its transmitters (BLE tag addresses): the source hashes
        # them with the deployment's epoch nonces, as the pipeline does for frames
        if nonces is not None and nonce_secret is not None:
            raise ConfigError("give --nonces or --nonce-secret, not both")
        if nonces is not None:
            inbox = nonce_inbox(nonces, keys_dir, schedule.epoch_s, schedule.grace_s, wait_s=0.0)
            options["hasher"] = MacHasher(inbox, epoch_s)
        elif nonce_secret is not None:
            options["hasher"] = MacHasher(DerivedNonces.from_file(nonce_secret), epoch_s)
    if channels is not None:
        if scheme not in ("wifi", "serial"):
            raise ConfigError(
                "--channels needs a wifi: source (hopped with iw) or a serial: DF board "
                "(its scan plan)"
            )
        options["channels"] = parse_channels(channels)
        if scheme == "wifi":
            options["dwell_s"] = dwell
        else:
            options["dwell_ms"] = max(1, round(dwell * 1000))
    if cues is not None:
        if channels is None or keys_dir is None:
            raise ConfigError("--cues needs --channels (the plan cues interrupt) and --keys")
        options["cues"] = SchedulerConfig()
    if any_link_type:
        if scheme != "wifi":
            raise ConfigError("--any-link-type applies to wifi: sources only")
        options["any_link_type"] = True
    source = rfsas_hw.sources.open(spec, **options)
    _, _, target = spec.partition(":")
    inputs = [target if scheme == "pcap" else "", calibration_path or "", nonce_secret or ""]
    try:
        listeners = build_listeners(
            out,
            fmt,
            send,
            keys_dir,
            where,
            inputs=inputs,
            force=force,
            epoch_s=epoch_s,
            ros2=ros2,
            preauth=deployment_nonces(pipeline),
        )
    except BaseException:
        source.close()
        raise
    scheduler = getattr(source, "scheduler", None)
    if cues is not None and scheduler is not None and keys_dir is not None:
        try:
            trust = KeyStore.open(keys_dir).trust
            scheduler.inbox = CueInbox(CueReceiver(trust, transport=open_transport(cues, "recv")))
        except BaseException:
            source.close()
            raise
        listeners.add(NoteHeard(scheduler, source.now_s))  # type: ignore[attr-defined]
    console.print(f"reading {spec}; Ctrl-C ends the run", highlight=False)
    summary = Runner(source, pipeline, listeners, duration_s=duration).run()
    finish_run(
        summary,
        f"live on {spec}",
        out=out,
        json_summary=json_summary,
        interrupt_is_failure=False,
    )
