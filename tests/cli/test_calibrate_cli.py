"""``rfsas calibrate`` as a user runs it: files in, files and a summary out, clean errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from rfsas_hw.cli.main import main


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as exc:
        main([*args])
        raise SystemExit(0)
    out = capsys.readouterr()
    return int(exc.value.code or 0), out.out, out.err


@pytest.mark.extra("plot")
def test_fit_plot_and_check(
    tmp_path: Path, repo_root: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cal, png = tmp_path / "c.yaml", tmp_path / "c.png"
    code, out, err = run(
        [
            "calibrate",
            str(repo_root / "calibration/example_turntable.csv"),
            "-o",
            str(cal),
            "--plot",
            str(png),
        ],
        capsys,
    )
    assert code == 0, err
    assert "K_D" in out and "field of view" in out
    assert cal.exists() and png.stat().st_size > 10_000
    code, out, err = run(
        [
            "calibrate",
            "--check",
            str(cal),
            str(repo_root / "calibration/example_turntable_check.csv"),
        ],
        capsys,
    )
    assert code == 0, err
    assert "consistent (σ within 1.2×" in out and "NOT" not in out


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("angle_deg,rssi1_dbm\n0,-50\n", r"line 1: missing column 'rssi2_dbm'"),
        (
            "angle_deg,rssi1_dbm,rssi2_dbm\n0,-50,-51\n1,abc,-50\n",
            r"line 3: column 'rssi1_dbm': 'abc' is not a number",
        ),
        ("", r"empty file"),
        ("angle_deg,rssi1_dbm,rssi2_dbm\n", r"no samples after the header"),
    ],
)
def test_bad_csv_gives_one_line_and_exit_2(
    tmp_path: Path, content: str, message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    import re

    path = tmp_path / "bad.csv"
    path.write_text(content)
    code, _, err = run(["calibrate", str(path), "-o", str(tmp_path / "c.yaml")], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "bad.csv" in lines[0]
    assert re.search(message, lines[0])


def test_flat_curve_has_no_fov(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "flat.csv"
    # two readings per angle: enough samples for a fit, but no slope to fit
    rows = ["angle_deg,rssi1_dbm,rssi2_dbm"] + [
        f"{a},{-50 - (a % 2)},{-50 + (a % 2)}" for a in range(-30, 31) for _ in range(2)
    ]
    path.write_text("\n".join(rows) + "\n")
    code, _, err = run(["calibrate", str(path), "-o", str(tmp_path / "c.yaml")], capsys)
    assert code == 2 and "not monotonic around boresight" in err


def test_bad_calibration_file_gives_exit_2(
    tmp_path: Path, repo_root: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = (
        (repo_root / "calibration/example_cal.yaml").read_text().replace("version: 1", "version: 9")
    )
    cal = tmp_path / "v9.yaml"
    cal.write_text(text)
    code, _, err = run(
        [
            "calibrate",
            "--check",
            str(cal),
            str(repo_root / "calibration/example_turntable_check.csv"),
        ],
        capsys,
    )
    assert code == 2 and "v9.yaml: version: 9 is not supported" in err
    cal.write_text(
        text.replace("version: 9", "version: 1").replace("mode: linear", "mode: linear\nextra: 1")
    )
    code, _, err = run(
        [
            "calibrate",
            "--check",
            str(cal),
            str(repo_root / "calibration/example_turntable_check.csv"),
        ],
        capsys,
    )
    assert code == 2 and "unknown key 'extra'" in err


def test_usage_errors_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["calibrate", "--check", "only-one.yaml"], capsys)
    assert code == 2 and "--check takes CAL.yaml SAMPLES.csv" in err
