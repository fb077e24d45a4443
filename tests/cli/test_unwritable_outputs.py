"""An output where no file can be made is refused before any work, by every command alike.

As root a directory's mode bits do not stop a write, so the tests use a place
no one can write in: a process's folder under ``/proc``, and a path under a
regular file.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from clihelp import run

from rfsas_hw.cli.exitcodes import BAD_INPUT
from rfsas_hw.errors import ConfigError
from rfsas_hw.outpaths import check_output, check_writable_dir

UNWRITABLE = Path("/proc/self")
"""A directory that exists and holds no file of ours, whoever runs the tests."""

needs_proc = pytest.mark.skipif(
    not sys.platform.startswith("linux") or not UNWRITABLE.is_dir(), reason="needs Linux /proc"
)

NCAP = ["ncap", "--scenarios", "CPNA", "--speeds", "20", "--controllers", "los", "--seeds", "1",
        "--workers", "0", "--no-plots"]  # fmt: skip
CITY = ["city", "run", "--duration", "2", "--vehicles", "1", "--pedestrians", "1", "--bicycles",
        "0", "--rfsas", "off", "--no-png"]  # fmt: skip


@needs_proc
@pytest.mark.parametrize("args", [NCAP, CITY], ids=["ncap", "city run"])
def test_an_output_directory_no_file_can_be_made_in_is_refused_first(
    args: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run([*args, "--out", str(UNWRITABLE)], capsys)
    assert code == BAD_INPUT, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("error: --out /proc/self: cannot create files in"), err
    assert out == ""  # nothing ran: no table, no "runs →"


@needs_proc
def test_a_file_output_in_such_a_directory_is_refused_by_the_check() -> None:
    with pytest.raises(ConfigError, match="cannot create files in /proc"):
        check_output(UNWRITABLE / "summary.json", what="--out")


def test_a_file_in_the_way_is_named(tmp_path: Path) -> None:
    (tmp_path / "afile").write_text("x\n")
    with pytest.raises(ConfigError, match="afile is not a directory"):
        check_writable_dir(tmp_path / "afile" / "sub" / "deeper", what="--out")


def test_a_directory_still_to_be_made_is_judged_by_the_one_above(tmp_path: Path) -> None:
    target = tmp_path / "new" / "deeper"
    assert check_writable_dir(target) == target
    assert not (tmp_path / "new").exists()  # the check makes nothing
    assert list(tmp_path.iterdir()) == []  # and leaves no probe file behind


def test_the_refusal_names_the_option_as_help_shows_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "afile").write_text("x\n")
    bad = str(tmp_path / "afile" / "r.jsonl")
    code, _, err = run(["sumo", "run", "--seeds", "1", "--out", bad], capsys)
    assert code == BAD_INPUT and f"error: --out {bad}:" in err, err
