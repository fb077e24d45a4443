"""The shared vectors: committed file == regenerated, Python passes them, C passes them."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from rfsas_hw.board import vectors
from rfsas_hw.board.messages import MESSAGE_TYPES

REPO = Path(__file__).resolve().parents[2]
VECTORS = REPO / "firmware_protocol" / "vectors" / "vectors.txt"
SPEC = REPO / "firmware_protocol" / "SPEC.md"
HEADER = REPO / "firmware_protocol" / "c" / "rfsas_board.h"
C_SOURCE = REPO / "firmware_protocol" / "c" / "rfsas_board.c"


def test_committed_vectors_equal_regenerated() -> None:
    fresh = vectors.format_vectors(vectors.all_vectors())
    assert VECTORS.read_text(encoding="ascii") == fresh, (
        "firmware_protocol/vectors/vectors.txt is stale: run "
        "`python -m rfsas_hw.board.vectors firmware_protocol/vectors/vectors.txt`"
    )


def test_vectors_cover_what_the_spec_promises() -> None:
    parsed = vectors.parse_vectors(VECTORS.read_text(encoding="ascii"))
    names = {v.name for v in parsed}
    kinds = " ".join(e for v in parsed for e in v.expect)
    types = {int(m) for m in re.findall(r"frame 0x([0-9a-f]{2})", kinds) for m in [int(m, 16)]}
    assert {cls.TYPE for cls in MESSAGE_TYPES} <= types
    for kind in (
        "cobs",
        "short",
        "magic",
        "incompatible",
        "length",
        "unknown_type",
        "crc",
        "payload",
        "truncated",
    ):
        assert f"error {kind}" in kinds, kind
    assert {"cobs_run_254", "cobs_run_255", "garbage_fake_start", "crc_wrong"} <= names


@pytest.mark.parametrize(
    "vector", vectors.parse_vectors(VECTORS.read_text(encoding="ascii")), ids=lambda v: v.name
)
def test_python_passes_vector(vector: vectors.Vector) -> None:
    assert vectors.expectations(vector.wire) == vector.expect


def test_cobs_run_vectors_have_the_runs_they_claim() -> None:
    from rfsas_hw.board.framing import cobs_decode

    by_name = {v.name: v for v in vectors.parse_vectors(VECTORS.read_text(encoding="ascii"))}
    for name, run in (("cobs_run_254", 254), ("cobs_run_255", 255)):
        body = bytes(cobs_decode(by_name[name].wire[:-1]))
        assert 0 not in body[3 : 3 + run] and body[3 + run] == 0, name
    body = bytes(cobs_decode(by_name["cobs_run_254_at_end"].wire[:-1]))
    assert 0 not in body[-254:] and body[-255] == 0


def test_spec_and_c_header_carry_the_code_layouts_and_seeds() -> None:
    spec = SPEC.read_text(encoding="utf-8")
    block = spec.split("<!-- layouts:begin -->")[1].split("<!-- layouts:end -->")[0]
    assert [ln for ln in block.splitlines() if ln and not ln.startswith("```")] == [
        cls.LAYOUT for cls in MESSAGE_TYPES
    ]
    c_source = C_SOURCE.read_text(encoding="ascii")
    for cls in MESSAGE_TYPES:
        name = cls.LAYOUT.split(" ", 1)[0]
        row = f"| 0x{cls.TYPE:02X} | {name} |"
        assert row in spec, row
        assert f"| 0x{cls.CRC_EXTRA:02X} |" in spec.split(row)[1].splitlines()[0], name
        assert f"case RFSAS_{name}: return 0x{cls.CRC_EXTRA:02X};" in c_source, name
        assert f"RFSAS_{name} = 0x{cls.TYPE:02X}" in HEADER.read_text(encoding="ascii"), name


@pytest.mark.skipif(
    shutil.which("cc") is None and shutil.which("make") is None, reason="no C compiler"
)
def test_c_reference_passes_vectors(tmp_path: Path) -> None:
    exe = tmp_path / "test_vectors"
    c_dir = REPO / "firmware_protocol" / "c"
    subprocess.run(
        [
            "cc",
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-pedantic",
            "-O1",
            "-o",
            str(exe),
            str(c_dir / "rfsas_board.c"),
            str(c_dir / "test_vectors.c"),
        ],
        check=True,
        capture_output=True,
        text=True,
    )
    good = subprocess.run([str(exe), str(VECTORS)], capture_output=True, text=True)
    assert good.returncode == 0, good.stderr
    assert "0 failures" in good.stdout
    # the C program must notice a wrong expectation
    broken = tmp_path / "broken.txt"
    broken.write_text(VECTORS.read_text().replace("rssi_dbm=-47,-53", "rssi_dbm=-47,-52", 1))
    bad = subprocess.run([str(exe), str(broken)], capture_output=True, text=True)
    assert bad.returncode == 1 and "msg_measurement" in bad.stderr
