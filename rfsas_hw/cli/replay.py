"""``rfsas replay``: a recorded capture through the sensor pipeline into bearings."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click
from rich.console import Console

import rfsas_hw.sources
from rfsas_hw.cli.ros2opts import live_options
from rfsas_hw.cli.sensoropts import (
    PROGRESS_MIN_BYTES,
    build_listeners,
    build_pipeline,
    deployment_nonces,
    epoch_schedule,
    finish_run,
    parse_pose,
    progress_bar,
    sensor_options,
)
from rfsas_hw.errors import ConfigError
from rfsas_hw.privacy.hashing import DerivedNonces, MacHasher
from rfsas_hw.runner import Runner
from rfsas_hw.sources.registry import parse_spec, schemes, source_class


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
    console = Console(stderr=True)
    where = parse_pose(pose, origin)
    epoch_schedule(epoch_s)
    spec = capture_spec(capture)
    scheme, _ = parse_spec(spec)
    options: dict[str, Any] = {"errors": errors}
    pipeline = None
    if source_class(scheme).yields_bearings:
        # an AoA unit measures the angle itself: no calibration; it hashes its ids
        # with the deployment's nonces when given, as live does
        if nonce_secret is not None and getattr(source_class(scheme), "hashes_ids", False):
            options["hasher"] = MacHasher(DerivedNonces.from_file(nonce_secret), epoch_s)
    else:
        pipeline = build_pipeline(
            calibration_path,
            sensor_id,
            where,
            min_snr_db,
            nonce_secret=nonce_secret,
            epoch_s=epoch_s,
        )
    if speed is not None and speed <= 0:
        raise ConfigError(f"--speed must be positive, got {speed}")
    if spec.startswith("pcap:"):
        options["n_antennas"] = n_antennas
    source = rfsas_hw.sources.open(spec, **options)
    inputs = [*capture_paths(capture), calibration_path or "", nonce_secret or ""]
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
    total = source.stats.extra.get("bytes_total")
    runner = Runner(
        source,
        pipeline,
        listeners,
        realtime=realtime or retime or speed is not None,
        speed=speed or 1.0,
        retime=retime,
    )
    if total and total >= PROGRESS_MIN_BYTES:
        with progress_bar(console) as bar:
            task = bar.add_task(f"replay {Path(capture).name}", total=total)
            runner.progress = lambda done, _total: bar.update(task, completed=done)
            summary = runner.run()
    else:
        summary = runner.run()
    finish_run(
        summary,
        f"replay of {capture}",
        out=out,
        json_summary=json_summary,
        interrupt_is_failure=True,
    )
