"""``rfsas live``: bearings from a live source (monitor-mode Wi-Fi, a pcap stream, a DF board)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click
from rich.console import Console

from rfsas_hw.cli.linkopts import NONCES_HELP
from rfsas_hw.cli.options import duration_option
from rfsas_hw.cli.ros2opts import live_options
from rfsas_hw.cli.sensoropts import finish_run, sensor_config, sensor_options, start_sensor
from rfsas_hw.errors import ConfigError
from rfsas_hw.sources.registry import parse_spec
from rfsas_hw.sources.schedule import SchedulerConfig


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
@duration_option("Stop after this many seconds.")
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
    prove_motion_deg: float | None,
    moving_mount: bool,
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
    scheme, _ = parse_spec(spec)
    options: dict[str, Any] = {"errors": errors}
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
        options["cues"] = SchedulerConfig()
    if any_link_type:
        if scheme != "wifi":
            raise ConfigError("--any-link-type applies to wifi: sources only")
        options["any_link_type"] = True
    _, _, target = spec.partition(":")
    config = sensor_config(
        spec,
        source_options=options,
        inputs=[target if scheme == "pcap" else "", calibration_path or "", nonce_secret or ""],
        calibration_path=calibration_path,
        out=out,
        force=force,
        epoch_s=epoch_s,
        fmt=fmt,
        sensor_id=sensor_id,
        pose=pose,
        origin=origin,
        min_snr_db=min_snr_db,
        prove_motion_deg=prove_motion_deg,
        moving_mount=moving_mount,
        nonce_secret=nonce_secret,
        send=send,
        keys_dir=keys_dir,
        ros2=ros2,
        nonces=nonces,
        cues=cues,
        duration_s=duration,
    )
    app = start_sensor(config)
    Console(stderr=True).print(f"reading {spec}; Ctrl-C ends the run", highlight=False)
    summary = app.run()
    finish_run(
        summary,
        f"live on {spec}",
        out=out,
        json_summary=json_summary,
        interrupt_is_failure=False,
    )
