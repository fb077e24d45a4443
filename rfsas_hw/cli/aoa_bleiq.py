"""``rfsas aoa emulate bleiq``: the IQ reports of a modelled BLE antenna array, written to a
file (HCI events in btsnoop or H4, or the console text of Zephyr's direction-finding
sample) or published to an MQTT broker as Silicon Labs' AoA locator host does."""

from __future__ import annotations

import dataclasses
import time
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
from rfsas_hw.sources.ble_iq import REFERENCE_SAMPLES, IqReport, ble_channel_mhz
from rfsas_hw.sources.ble_iq_emulator import btsnoop_file, h4_stream, iq_reports
from rfsas_hw.sources.ble_iq_silabs import address_id, encode_iq_json, report_topic
from rfsas_hw.sources.ble_iq_zephyr import format_stream

TEXT_SUFFIXES = (".txt", ".log")
EMULATED_LOCATOR = 0x0C4314F4634A
"""The emulated locator board's address (its MQTT id is ``ble-pd-0C4314F4634A``)."""
EMULATED_TAG = 0xC01122334455
"""The emulated tag's address."""
CTE_US = 160
"""Length of the emulated CTE, µs: 4 µs guard, 8 µs reference, then the slots."""


@click.command("bleiq")
@out_option(
    "File to write: .h4 a raw H4 stream, .txt or .log the Zephyr sample's console text, "
    "anything else btsnoop.",
    dest="output",
)
@click.option(
    "--mqtt",
    "mqtt_url",
    metavar="mqtt://HOST[:PORT]",
    help="Publish the reports to this broker as Silicon Labs' locator host does, instead.",
)
@click.option(
    "--slot",
    type=click.Choice(["1", "2"]),
    help="Switch and sample slot, µs [default: 2 for files, 1 for --mqtt].",
)
@click.option(
    "--interval",
    type=click.FloatRange(0.0, 10.0),
    default=0.005,
    show_default=True,
    help="Seconds between published messages (--mqtt).",
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
@click.option(
    "--packets",
    type=click.IntRange(1, 100_000),
    default=300,
    show_default=True,
    help="IQ reports to emit, one per packet, each at a random true angle.",
)
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
    output: Path | None,
    mqtt_url: str | None,
    slot: str | None,
    interval: float,
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
    """IQ reports of emitters all round an N-element circular array (connectionless, one
    160 µs CTE per packet).

    The true angles are the first ``--packets`` draws of ``uniform(−180, 180)``
    from numpy's ``default_rng(--seed)``: the same seed gives the same packets.

    \b
    rfsas aoa emulate bleiq -o iq.btsnoop --calibration-out array.yaml
    rfsas replay 'bleiq:iq.btsnoop?elements=8' --calibration array.yaml --out bearings.jsonl
    rfsas aoa emulate bleiq -o console.txt   # 'bleiq+zephyr:console.txt?elements=8&channel=17'
    rfsas aoa emulate bleiq --mqtt mqtt://127.0.0.1:1883   # 'bleiq+mqtt://127.0.0.1?elements=8'
    """
    if (output is None) == (mqtt_url is None):
        raise click.UsageError("give -o FILE or --mqtt URL (one of them)")
    if output is not None:
        check_output(output, force=force)
    if calibration_out is not None:
        check_output(calibration_out, [output] if output is not None else [], force=force)
    slot_us = int(slot) if slot is not None else (1 if mqtt_url is not None else 2)
    freq = ble_channel_mhz(channel)
    geometry = ArrayGeometry.uca(elements, radius * C_MPS / (freq * 1e6))
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-180.0, 180.0, packets)
    offsets = rng.uniform(-cfo, cfo, packets)
    n_samples = REFERENCE_SAMPLES + (CTE_US - 12) // (2 * slot_us)
    reports = iq_reports(
        geometry, list(range(elements)), theta, snr, offsets, rng, channel_index=channel,
        slot_us=slot_us, n_samples=n_samples,
    )  # fmt: skip
    if mqtt_url is not None:
        _publish(mqtt_url, reports, interval)
        click.echo(f"published {packets} IQ reports to {mqtt_url}", err=True)
    else:
        assert output is not None
        if output.suffix == ".h4":
            data = h4_stream(reports)
        elif output.suffix in TEXT_SUFFIXES:
            data = format_stream(reports, ["0"] * len(reports), {0: _colons(EMULATED_TAG)}).encode()
        else:
            data = btsnoop_file(reports, 1_800_000_000 * 10**9)
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


def _colons(address: int) -> str:
    return ":".join(f"{address:012X}"[i : i + 2] for i in range(0, 12, 2))


def _publish(url: str, reports: list[IqReport], interval: float) -> None:
    """Publish ``reports`` on the locator host's topic, ``interval`` seconds apart.

    Raises:
        LinkError: a bad URL, no broker, or a publish that failed.
    """
    from rfsas_hw.link.mqtt import MqttTransport, parse_mqtt_url
    from rfsas_hw.link.topics import Route

    route = Route(report_topic(address_id(EMULATED_LOCATOR, False), address_id(EMULATED_TAG)))
    transport = MqttTransport(parse_mqtt_url(url), "send")
    try:
        for report in reports:
            transport.publish(route, encode_iq_json(report))
            if interval:
                time.sleep(interval)
    finally:
        transport.close()
