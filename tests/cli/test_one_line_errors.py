"""Bad options and bad files end in one line and exit code 2, never a traceback; a BOM or a
UTF-8 header is read, not refused."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from clihelp import REPO, run, write_calibration, write_capture

from rfsas_hw.cli.exitcodes import BAD_INPUT, FAILED, OK
from rfsas_hw.df import read_samples_csv
from rfsas_hw.errors import DataFormatError
from rfsas_hw.sources.turntable import read_angle_log

TURNTABLE = REPO / "calibration" / "example_turntable.csv"


@pytest.mark.parametrize(
    "args",
    [
        ["calibrate", str(TURNTABLE), "-o", "{tmp}/c.yaml", "--grid-step", "0"],
        ["calibrate", str(TURNTABLE), "-o", "{tmp}/c.yaml", "--noise-floor", "nan"],
        ["calibrate", str(TURNTABLE), "-o", "{tmp}/c.yaml", "--step-db", "-1"],
        ["nonces", "serve", "--keys", "{tmp}", "--to", "a=udp://127.0.0.1:9", "--resend", "0"],
        ["nonces", "serve", "--keys", "{tmp}", "--to", "a=udp://127.0.0.1:9", "--epoch", "0.1"],
        ["board", "emulate", "--tcp", "-5"],
        ["board", "emulate", "--tcp", "65536"],
        ["board", "info", "loop://", "--timeout", "0"],
        ["live", "pcap:x.pcap", "--calibration", "c.yaml", "--out", "b.jsonl", "--duration", "inf"],
        ["replay", "x.pcap", "--calibration", "c.yaml", "--out", "b.jsonl", "--epoch", "0"],
        ["replay", "x.pcap", "--calibration", "c.yaml", "--out", "b.jsonl", "--pose", "1,2,nan"],
        ["plan", "--trials", "0"],
        ["plan", "--dwell", "-3"],
        ["link", "watch", "--listen", "udp://127.0.0.1:99999", "--keys", "{tmp}"],
    ],
    ids=lambda a: " ".join(a[:2] + a[-2:]),
)
def test_bad_options_are_one_line_and_exit_2(
    args: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = run([a.replace("{tmp}", str(tmp_path)) for a in args], capsys)
    assert code == BAD_INPUT, err
    assert "Traceback" not in err and err.strip()


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "NUL byte"),
        ("format: rfsas-calibration\n".encode("utf-16"), "UTF-16"),
        (b"format: caf\xe9\n", "not UTF-8"),
        (b"[" * 500 + b"]" * 500, "nested deeper"),
        (b"version: " + b"9" * 5000 + b"\n", "too large to read"),
    ],
)
def test_a_calibration_file_that_is_not_yaml_text(
    content: bytes, needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cap = write_capture(tmp_path / "cap.pcap", n=20, span_s=2.0)
    cal = tmp_path / "cal.yaml"
    cal.write_bytes(content)
    code, _, err = run(
        ["replay", str(cap), "--calibration", str(cal), "--out", str(tmp_path / "b.jsonl")],
        capsys,
    )
    assert code == BAD_INPUT and needle in err and str(cal) in err
    assert len(err.strip().splitlines()) == 1


def test_a_bom_in_a_csv_header_is_read(tmp_path: Path) -> None:
    path = tmp_path / "bom.csv"
    path.write_bytes(b"\xef\xbb\xbf" + TURNTABLE.read_bytes())
    assert len(read_samples_csv(path).angle_deg) == len(read_samples_csv(TURNTABLE).angle_deg)


def test_a_utf16_csv_is_named(tmp_path: Path) -> None:
    path = tmp_path / "u16.csv"
    path.write_bytes(TURNTABLE.read_text().encode("utf-16"))
    with pytest.raises(DataFormatError, match="UTF-16"):
        read_samples_csv(path)


def test_millisecond_times_in_an_angle_log_are_named(tmp_path: Path) -> None:
    path = tmp_path / "angles.csv"
    path.write_text("time_s,angle_deg\n1763800000000,-90\n1763800000100,-89\n")
    with pytest.raises(DataFormatError, match=r"line 2: .*milliseconds"):
        read_angle_log(path)


def test_calibrate_check_exit_code_and_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cal = write_calibration(tmp_path / "cal.yaml")
    check = REPO / "calibration" / "example_turntable_check.csv"
    code, out, err = run(["calibrate", "--check", str(cal), str(check), "--json"], capsys)
    report = json.loads(out)
    assert code == (OK if report["consistent"] else FAILED), err
    assert {"error_over_sigma", "rms_error_deg", "valid", "limit"} <= set(report)
    # the same table checked against samples from swapped antennas is inconsistent
    swapped = tmp_path / "swapped.csv"
    lines = check.read_text().splitlines()
    head = lines[0].split(",")
    i1, i2 = head.index("rssi1_dbm"), head.index("rssi2_dbm")
    rows = []
    for line in lines[1:]:
        cells = line.split(",")
        cells[i1], cells[i2] = cells[i2], cells[i1]
        rows.append(",".join(cells))
    swapped.write_text("\n".join([lines[0], *rows]) + "\n")
    code, out, err = run(["calibrate", "--check", str(cal), str(swapped), "--json"], capsys)
    assert code == FAILED and json.loads(out)["consistent"] is False
    assert "NOT consistent" in err


def test_a_pem_key_of_an_unknown_algorithm_is_one_line(tmp_path: Path) -> None:
    import base64

    from rfsas_hw.errors import KeyStoreError
    from rfsas_hw.link.keys import KeyStore

    store = KeyStore.create(tmp_path / "rsu-1", "sensor")
    pem = (store.path / "sign.key").read_text().splitlines()
    der = base64.b64decode("".join(line for line in pem if not line.startswith("-----")))
    ec_oid = bytes.fromhex("06072a8648ce3d0201")  # id-ecPublicKey, 1.2.840.10045.2.1
    assert ec_oid in der
    body = base64.b64encode(der.replace(ec_oid, ec_oid[:-1] + b"\x03")).decode()
    (store.path / "sign.key").write_text(f"{pem[0]}\n{body}\n{pem[-1]}\n")
    with pytest.raises(KeyStoreError, match="not a readable private key") as info:
        KeyStore.open(store.path).signer()
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("channel", ["99999999999999999999", "-1", "70000"])
def test_a_channel_out_of_range_in_a_sweep_is_named(tmp_path: Path, channel: str) -> None:
    path = tmp_path / "s.csv"
    path.write_text(f"angle_deg,rssi1_dbm,rssi2_dbm,channel\n0,-50,-51,{channel}\n")
    with pytest.raises(DataFormatError, match="line 2: column 'channel'"):
        read_samples_csv(path)
