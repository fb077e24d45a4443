"""The console text of Zephyr's direction-finding samples: lines as their printk calls
write them, errors with line numbers, fuzzing, a port, and bearings end to end."""

from __future__ import annotations

import dataclasses
import json
import random
import re
from pathlib import Path

import numpy as np
import pytest
import serial
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.df import load_calibration
from rfsas_hw.df.array import C_MPS, ArrayGeometry
from rfsas_hw.df.arraycal import ArrayCalibration, ElementCalibration
from rfsas_hw.df.arraycsi import array_df_result
from rfsas_hw.df.arrayfit import crb_deg
from rfsas_hw.df.estimate import estimate
from rfsas_hw.errors import CaptureFormatError, SourceError
from rfsas_hw.sources import open_source
from rfsas_hw.sources.ble_iq import ble_channel_mhz
from rfsas_hw.sources.ble_iq_emulator import iq_reports
from rfsas_hw.sources.ble_iq_zephyr import ZephyrIqParser, ZephyrReport, format_report

REPO = Path(__file__).resolve().parents[2]
_load_commands()

# direction_finding_connectionless_rx with the sample printing switched on:
# printk("CTE[%u]: samples type: %s, samples count %d, cte type %s, slot durations: %u [us], "
#        "packet status %s, RSSI %i\n", ...) and printk(" IQ[%d]: %d, %d\n", idx, i, q)
CONNECTIONLESS = (
    "CTE[0]: samples type: 8 bits int, samples count 9, cte type AOA, slot durations: 2 [us], "
    "packet status CRC OK, RSSI -604\n"
    " IQ[0]: 10, 0\n IQ[1]: 9, 3\n IQ[2]: 7, 6\n IQ[3]: 4, 9\n IQ[4]: 0, 10\n"
    " IQ[5]: -3, 9\n IQ[6]: -7, 6\n IQ[7]: -9, 3\n IQ[8]: -128, -128\n"
)
# direction_finding_central: the peer's address as bt_addr_le_to_str writes it
CONNECTION = (
    "CTE[C0:11:22:33:44:55 (random)]: samples type: 16 bits int, samples count 9, "
    "cte type AOD 1 [us], slot durations: 1 [us], packet status CRC not OK, CTE Info OK, "
    "RSSI -710\n" + "".join(f" IQ[{k}]: {300 * k}, {-k}\n" for k in range(9))
)
# the samples' first release: no sample type, no sample lines; a report without samples
NO_RESOURCES = (
    "CTE[1]: samples count 0, cte type AOA, slot durations: 2 [us], "
    "packet status No resources, RSSI -800\n"
)


def _parse(text: str, channel: int = 0) -> list[ZephyrReport | CaptureFormatError]:
    parser = ZephyrIqParser("console.txt", channel)
    out: list[ZephyrReport | CaptureFormatError] = []
    lines = text.splitlines()
    for n, line in enumerate(lines, 1):
        out += parser.feed(line, n)
    return out + parser.finish(len(lines))


def test_connectionless_lines() -> None:
    (item,) = _parse(CONNECTIONLESS, channel=17)
    assert isinstance(item, ZephyrReport)
    r = item.report
    assert (r.kind, r.handle, r.channel_index, r.cte_type, r.slot_us, r.packet_status) == (
        "connectionless", 0, 17, 0, 2, 0,
    )  # fmt: skip
    assert r.rssi_dbm == pytest.approx(-60.4) and item.key == 0 and item.line == 1
    assert r.iq[0] == 10 + 0j and r.iq[5] == -3 + 9j
    assert np.isnan(r.iq[8]) and r.invalid == 1  # -128: the "no valid sample" sentinel
    assert "\n".join(format_report(r, "0")) + "\n" == CONNECTIONLESS


def test_connection_lines_key_by_the_peer_address() -> None:
    (item,) = _parse(CONNECTION)
    assert isinstance(item, ZephyrReport)
    r = item.report
    assert r.kind == "connection" and item.key == 0xC01122334455
    assert (r.cte_type, r.slot_us, r.packet_status) == (1, 1, 1)
    assert r.iq[8] == 2400 - 8j  # a 16-bit sample
    assert "\n".join(format_report(r, "C0:11:22:33:44:55 (random)", 16)) + "\n" == CONNECTION


def test_first_release_header_and_no_resources() -> None:
    (item,) = _parse(NO_RESOURCES)
    assert isinstance(item, ZephyrReport)
    assert item.report.packet_status == 0xFF and len(item.report.iq) == 0


def test_synced_line_gives_the_advertiser_address() -> None:
    synced = (
        "PER_ADV_SYNC[0]: [DEVICE]: D0:01:02:03:04:05 (random) synced, "
        "Interval 0x0050 (100 ms), PHY LE 2M\n"
    )
    items = _parse("[DEVICE]: scan noise\n" + synced + CONNECTIONLESS)
    assert [i.key for i in items if isinstance(i, ZephyrReport)] == [0xD00102030405]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        # the sample line of IQ[4] lost: the next report's header cuts this one short
        (CONNECTIONLESS.replace(" IQ[4]: 0, 10\n", ""), r"line 6: IQ\[5\] where IQ\[4\] was due"),
        (
            CONNECTIONLESS.split(" IQ[4]")[0] + NO_RESOURCES,
            r"line 1: .*announces 9 samples, 4 came",
        ),
        (CONNECTIONLESS.split(" IQ[4]")[0], r"line 1: .*4 came \(the input ended\)"),
        (
            CONNECTIONLESS.split("\n")[0] + "\n" + NO_RESOURCES,
            r"line 1: .*CONFIG_DF_LOCATOR_APP_IQ",
        ),
        (CONNECTIONLESS.replace("IQ[3]: 4, 9", "IQ[3]: 4, 200"), r"line 5: .*outside 8-bit"),
        (CONNECTIONLESS.replace("count 9", "count 5"), r"line 1: samples count 5"),
        (CONNECTIONLESS.replace("AOA", "AOX"), r"line 1: cte type 'AOX'"),
        (CONNECTIONLESS.replace("2 [us]", "3 [us]"), r"line 1: slot durations 3"),
        (CONNECTIONLESS.replace("CRC OK", "CRC maybe"), r"line 1: packet status 'CRC maybe'"),
        (CONNECTIONLESS.replace("RSSI -604", "RSSI -604x"), r"line 1: a CTE line that is not"),
        (" IQ[0]: 1, 2\n", r"line 1: an IQ sample line outside a report"),
    ],
)
def test_bad_text_names_the_line(text: str, message: str) -> None:
    errors = [i for i in _parse(text) if isinstance(i, CaptureFormatError)]
    assert len(errors) == 1 and re.search(message, str(errors[0])), errors
    assert str(errors[0]).startswith("console.txt: line ")


def test_a_lost_line_costs_one_report_not_the_next() -> None:
    text = CONNECTIONLESS.replace(" IQ[7]: -9, 3\n", "") + CONNECTIONLESS
    items = _parse(text)
    assert [type(i).__name__ for i in items] == ["CaptureFormatError", "ZephyrReport"]


def test_error_messages_do_not_echo_addresses() -> None:
    bad = CONNECTION.replace("RSSI -710", "RSSI ?")
    errors = [str(i) for i in _parse(bad) if isinstance(i, CaptureFormatError)]
    assert errors and not any("C0:11" in e or "c01122" in e.lower() for e in errors)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.text(max_size=150), max_size=20))
def test_fuzz_lines_never_crash(lines: list[str]) -> None:
    parser = ZephyrIqParser("fuzz")
    for n, line in enumerate(lines, 1):
        for item in parser.feed(line, n):
            assert isinstance(item, ZephyrReport | CaptureFormatError)
    parser.finish(len(lines))


def _mutate(rng: random.Random, text: str) -> str:
    b = bytearray(text.encode())
    for _ in range(rng.choice((1, 2, 4))):
        op, at = rng.randrange(4), rng.randrange(len(b))
        if op == 0:
            b[at] = rng.choice(b"0123456789-,:[] \nCTEIQ\x00\xff")
        elif op == 1:
            del b[at : at + rng.randrange(1, 40)]
        elif op == 2:
            b[at:at] = b[rng.randrange(len(b)) :][: rng.randrange(1, 60)]
        else:
            b = b[:at]
        if not b:
            break
    return b.decode("utf-8", "replace")


def test_fuzz_mutated_consoles_through_the_source(tmp_path: Path) -> None:
    rng = random.Random(20261127)
    seed = CONNECTIONLESS + CONNECTION + NO_RESOURCES + CONNECTIONLESS
    path = tmp_path / "console.txt"
    for _ in range(300):
        path.write_text(_mutate(rng, seed))
        with open_source(f"bleiq+zephyr:{path}?elements=3") as src:
            for _batch in src:
                pass
            assert all(e.startswith(f"{path}: line ") for e in src.stats.errors)


FREQ_CH = 17
LAM = C_MPS / (ble_channel_mhz(FREQ_CH) * 1e6)
UCA = ArrayGeometry.uca(8, 0.6 * LAM)


def _array_cal():  # type: ignore[no-untyped-def]
    base = load_calibration(REPO / "calibration" / "example_cal.yaml")
    none = ElementCalibration(np.zeros(8), np.zeros(8))
    return dataclasses.replace(base, array=ArrayCalibration(UCA, none, ble_channel_mhz(FREQ_CH)))


def test_emulated_console_gives_bearings_all_round(tmp_path: Path) -> None:
    path = tmp_path / "console.txt"
    result = CliRunner().invoke(
        cli,
        ["aoa", "emulate", "bleiq", "-o", str(path), "--packets", "300", "--seed", "4"],
        catch_exceptions=False,
    )
    assert result.exit_code == 0, result.output
    theta = np.random.default_rng(4).uniform(-180.0, 180.0, 300)  # the command's draws
    with open_source(f"bleiq+zephyr:{path}?elements=8&channel={FREQ_CH}") as src:
        batch = next(iter(src))
        assert src.stats.extra["iq_reports"] == 300 and not src.stats.skipped
    assert int(batch.mac[0]) == 0xC01122334455  # the synced line's advertiser
    cal = _array_cal()
    mono = estimate(cal, batch.rssi_dbm[:, 0], batch.rssi_dbm[:, 1], batch.channel)
    res = array_df_result(cal, batch, mono)
    v = res.valid
    assert v.mean() > 0.98
    err = (res.angle_deg[v] - theta[v] + 180.0) % 360.0 - 180.0
    passes = batch.csi.h.shape[2] if batch.csi is not None else 0
    crb = crb_deg(UCA, theta[v], 25.0, ble_channel_mhz(FREQ_CH), snapshots=passes)
    rms, bound = float(np.sqrt(np.mean(err**2))), float(np.sqrt(np.mean(crb**2)))
    assert rms <= 1.2 * bound, (rms, bound)


def test_replay_of_a_console_writes_no_raw_address(tmp_path: Path) -> None:
    console, cal_path, out = tmp_path / "c.txt", tmp_path / "array.yaml", tmp_path / "b.jsonl"
    args = ["aoa", "emulate", "bleiq", "-o", str(console), "--calibration-out", str(cal_path)]
    assert CliRunner().invoke(cli, [*args, "--packets", "40"]).exit_code == 0
    result = CliRunner().invoke(
        cli,
        [
            *("replay", f"bleiq+zephyr:{console}?elements=8&channel=17"),
            *("--calibration", str(cal_path), "--out", str(out)),
        ],
        catch_exceptions=False,
    )
    assert result.exit_code == 0, result.output
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) >= 35
    blob = (out.read_text() + result.output).lower()
    for form in ("c0:11:22:33:44:55", "c01122334455", str(0xC01122334455)):
        assert form not in blob


class _Clock:
    def __init__(self) -> None:
        self.t = 1_800_000_000 * 10**9

    def __call__(self) -> int:
        self.t += 1_000_000
        return self.t


def test_a_port_stream_cut_anywhere_gives_the_same_reports() -> None:
    rng = np.random.default_rng(5)
    reports = iq_reports(UCA, list(range(8)), [10.0, -100.0, 170.0], 30.0, 0.0, rng)
    text = "boot noise\r\n" + "".join("\r\n".join(format_report(r, "2")) + "\r\n" for r in reports)
    port = serial.serial_for_url("loop://", timeout=0.05)
    got = []
    with open_source(
        "bleiq+zephyr:loop://?elements=8", port_factory=lambda *a, **k: port, clock=_Clock()
    ) as src:
        data = text.encode()
        for start in range(0, len(data), 333):  # chunks that end inside lines
            port.write(data[start : start + 333])
            for _ in range(5):
                batch = src.read(0.05)
                if batch is not None and len(batch):
                    got.append(batch)
        assert not src.stats.skipped
    times = np.concatenate([b.t_ns for b in got])
    assert len(times) == 3 and np.all(np.diff(times) > 0)
    assert [int(k) for b in got for k in b.mac] == [2, 2, 2]


def test_spec_errors_name_the_option(tmp_path: Path) -> None:
    path = tmp_path / "c.txt"
    path.write_text("")
    with pytest.raises(SourceError, match="elements=N"):
        open_source(f"bleiq+zephyr:{path}")
    with pytest.raises(SourceError, match="channel 45"):
        open_source(f"bleiq+zephyr:{path}?elements=4&channel=45")
    with pytest.raises(SourceError, match="unknown option 'bits'"):
        open_source(f"bleiq+zephyr:{path}?elements=4&bits=8")
    with pytest.raises(SourceError, match="cannot open serial port"):
        open_source(f"bleiq+zephyr:{tmp_path / 'no-such-tty'}?elements=4")
