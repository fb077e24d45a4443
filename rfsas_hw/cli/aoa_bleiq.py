"""``rfsas aoa emulate bleiq``: write the IQ reports of a modelled BLE antenna array to a file."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import click
import numpy as np

from rfsas_hw.cli.options import out_option
from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.df import fit_calibration, save_calibration
from rfsas_hw.df.array import C_MPS, ArrayGeometry
from rfsas_hw.df.arraycal import ArrayCalibration, ElementCalibration
from rfsas_hw.outpaths import check_output
from rfsas_hw.rf import GaussianBeamPair, ReceiverModel, turntable_sweep
from rfsas_hw.sources.ble_iq import ble_channel_mhz
from rfsas_hw.sources.ble_iq_emulator import btsnoop_file, h4_stream, iq_reports


@click.command("bleiq")
@out_option(
    "File to write: .h4 for a raw H4 stream, anything else btsnoop.",
    dest="output",
    required=True,
)
@click.option(
    "--calibration-out",
    type=OutputPath(),
    help="Also write a calibration with the array's geometry (ideal elements).",
)
@click.option(
    "--elements",
    type=click.IntRange(3, 16),
    default=8,
    show_default=True,
    help="Antennas of the circular array.",
)
@click.option(
    "--radius",
    type=click.FloatRange(0.1, 2.0),
    default=0.6,
    show_default=True,
    help="Array radius, wavelengths.",
)
@click.option("--packets", type=click.IntRange(1, 100_000), default=300, show_default=True)
@click.option("--snr", type=float, default=25.0, show_default=True, help="SNR per sample, dB.")
@click.option(
    "--cfo",
    type=click.FloatRange(0.0, 150_000.0),
    default=150_000.0,
    show_default=True,
    help="Carrier offsets drawn uniformly within ±this, Hz.",
)
@click.option(
    "--channel",
    type=click.IntRange(0, 39),
    default=17,
    show_default=True,
    help="BLE channel index.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option("--force", is_flag=True, help="Replace existing output files.")
def emulate_bleiq(
    output: Path,
    calibration_out: Path | None,
    elements: int,
    radius: float,
    packets: int,
    snr: float,
    cfo: float,
    channel: int,
    seed: int,
    force: bool,
) -> None:
    """IQ reports of emitters all round an N-element circular array (connectionless, 2 µs slots).

    The true angles are the first ``--packets`` draws of ``uniform(−180, 180)``
    from numpy's ``default_rng(--seed)``: the same seed gives the same packets.

    \b
    rfsas aoa emulate bleiq -o iq.btsnoop --calibration-out array.yaml
    rfsas replay 'bleiq:iq.btsnoop?elements=8' --calibration array.yaml --out bearings.jsonl
    """
    check_output(output, force=force)
    if calibration_out is not None:
        check_output(calibration_out, [output], force=force)
    freq = ble_channel_mhz(channel)
    geometry = ArrayGeometry.uca(elements, radius * C_MPS / (freq * 1e6))
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-180.0, 180.0, packets)
    offsets = rng.uniform(-cfo, cfo, packets)
    reports = iq_reports(
        geometry, list(range(elements)), theta, snr, offsets, rng, channel_index=channel
    )
    data = (
        h4_stream(reports)
        if output.suffix == ".h4"
        else btsnoop_file(reports, 1_800_000_000 * 10**9)
    )
    # a failed write (disk full) ends as OutputError through the commands' output guard
    output.write_bytes(data)
    click.echo(f"wrote {packets} IQ reports to {output}", err=True)
    if calibration_out is not None:
        ideal = ElementCalibration(np.zeros(elements), np.zeros(elements))
        # the file format needs an amplitude table; the array's bearings do not use it
        sweep = turntable_sweep(
            np.arange(-90.0, 90.5, 1.0), 5, -50.0, GaussianBeamPair(), ReceiverModel(), seed
        )
        amplitude = fit_calibration(
            sweep, antenna={"description": f"emulated {elements}-element BLE array"}
        )
        cal = dataclasses.replace(amplitude, array=ArrayCalibration(geometry, ideal, freq))
        save_calibration(cal, calibration_out)
        click.echo(f"wrote the array calibration to {calibration_out}", err=True)
