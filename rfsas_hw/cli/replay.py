"""``rfsas replay``: a recorded capture through the sensor pipeline into bearings."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click
from rich.console import Console

from rfsas_hw.cli.ros2opts import live_options
from rfsas_hw.cli.sensoropts import (
    PROGRESS_MIN_BYTES,
    finish_run,
    progress_bar,
    sensor_config,
    sensor_options,
    start_sensor,
)
from rfsas_hw.errors import ConfigError
from rfsas_hw.sources.registry import schemes


def capture_spec(capture: str) -> str:
    """A source spec for CAPTURE: a registered ``scheme:…`` as is, anything else as a pcap path."""
    scheme, sep, _ = capture.partition(":")
    if sep and scheme in schemes() and not Path(capture).exists():
        return capture
    return f"pcap:{capture}"


def capture_paths(capture: str) -> list[str]:
    """The files CAPTURE reads (``A.pcap+B.pcap`` is two), for the never-overwrite check."""
    spec = capture_spec(capture)
    if not spec.startswith("pcap:"):
        return []
    return [part for part in spec[len("pcap:") :].split("+") if part]


@click.command()
@click.argument("capture")
@sensor_options
@live_options
@click.option("--realtime", is_flag=True, help="Replay at the recorded pace instead of at once.")
@click.option(
    "--speed",
    type=float,
    default=None,
    help="Pace factor for recorded timing (implies --realtime): 2 = twice as fast.",
)
@click.option(
    "--retime",
    is_flag=True,
    help="Give frames the time they are replayed at (implies --realtime): feeds a live "
    "backend with --send as a sensor would.",
)
@click.option(
    "--antennas",
    "n_antennas",
    type=click.IntRange(2, 8),
    default=2,
    show_default=True,
    help="RSSI columns per observation (chain k → antenna k).",
)
def replay(
    capture: str,
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
    realtime: bool,
    speed: float | None,
    retime: bool,
    n_antennas: int,
    **ros2: Any,
) -> None:
    """Turn CAPTURE (pcap/pcapng, or A.pcap+B.pcap from two receivers) into bearings.

    \b
    rfsas replay capture.pcapng --calibration cal.yaml --out bearings.jsonl
    rfsas replay a.pcap+b.pcap --calibration cal.yaml --out bearings.csv --realtime --speed 4
    rfsas replay old.pcap --calibration cal.yaml --keys keys/rsu-1 --send udp://HOST:47000 --retime
    rfsas replay capture.pcap --calibration cal.yaml --out - --json | jq .
    """
    if speed is not None and speed <= 0:
        raise ConfigError(f"--speed must be positive, got {speed}")
    spec = capture_spec(capture)
    options: dict[str, Any] = {"errors": errors}
    if spec.startswith("pcap:"):
        options["n_antennas"] = n_antennas
    config = sensor_config(
        spec,
        source_options=options,
        inputs=[*capture_paths(capture), calibration_path or "", nonce_secret or ""],
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
        realtime=realtime or speed is not None,
        speed=speed or 1.0,
        retime=retime,
    )
    app = start_sensor(config)
    total = app.source.stats.extra.get("bytes_total")
    if total and total >= PROGRESS_MIN_BYTES:
        with progress_bar(Console(stderr=True)) as bar:
            task = bar.add_task(f"replay {Path(capture).name}", total=total)
            summary = app.run(progress=lambda done, _total: bar.update(task, completed=done))
    else:
        summary = app.run()
    finish_run(
        summary,
        f"replay of {capture}",
        out=out,
        json_summary=json_summary,
        interrupt_is_failure=True,
    )
