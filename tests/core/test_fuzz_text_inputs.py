"""Fuzz every text input with mutated files: one clear error or a valid result, never
another exception, and bounded memory.

Inputs: calibration YAML, scenario YAML, backend settings YAML, vehicle state,
turntable samples CSV, turntable angle log CSV, key cards and PEM private keys.
Mutations start from a valid file: byte and line edits, truncation, other
encodings (UTF-16, Latin-1, a BOM), binary noise, NUL bytes, very long lines,
deep nesting, YAML aliases and tags, huge numbers, and size blow-ups. The case
count is ``RFSAS_FUZZ_CASES / 50`` (at least 400; ``make fuzz`` runs 20,000).
"""

from __future__ import annotations

import os
import random
import resource
import shutil
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import pytest

from rfsas_hw.backend.service import load_backend_config
from rfsas_hw.backend.vehicle import load_vehicle
from rfsas_hw.df import load_calibration, read_samples_csv
from rfsas_hw.errors import RfsasError
from rfsas_hw.link.keys import KeyCard, KeyStore
from rfsas_hw.sources.turntable import read_angle_log
from rfsas_hw.twin.scenario import load_scenario

REPO = Path(__file__).resolve().parents[2]
CASES = max(400, int(os.environ.get("RFSAS_FUZZ_CASES", "20000")) // 50)
MAX_GROWTH_MB = 400
"""Most the resident size may grow over the whole run."""

Mutation = Callable[[random.Random, bytes], bytes]
Seeds = dict[str, tuple[bytes, Callable[[Path], object]]]


def flip(rng: random.Random, d: bytes) -> bytes:
    b = bytearray(d)
    for _ in range(rng.choice((1, 2, 5))):
        if b:
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
    return bytes(b)


def set_byte(rng: random.Random, d: bytes) -> bytes:
    b = bytearray(d)
    if b:
        b[rng.randrange(len(b))] = rng.choice(b"\x00\xff\x80:-[]{}&*!|>'\"#,\n\t ")
    return bytes(b)


def truncate(rng: random.Random, d: bytes) -> bytes:
    return d[: rng.randrange(len(d) + 1)]


def utf16(rng: random.Random, d: bytes) -> bytes:
    text = d.decode("utf-8", "replace")
    return text.encode(rng.choice(("utf-16", "utf-16-le", "utf-16-be")))


def latin1(rng: random.Random, d: bytes) -> bytes:
    return d.replace(b"a", b"\xe9", rng.randint(1, 5))


def bom(rng: random.Random, d: bytes) -> bytes:
    return b"\xef\xbb\xbf" + d


def binary(rng: random.Random, d: bytes) -> bytes:
    return rng.randbytes(rng.choice((1, 16, 4096)))


def long_line(rng: random.Random, d: bytes) -> bytes:
    pos = rng.randrange(len(d) + 1)
    return d[:pos] + rng.choice((b"9", b"a", b",", b"-")) * rng.choice((10_000, 300_000)) + d[pos:]


def swap_lines(rng: random.Random, d: bytes) -> bytes:
    lines = d.split(b"\n")
    if len(lines) > 2:
        i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
        lines[i], lines[j] = lines[j], lines[i]
    return b"\n".join(lines)


def drop_line(rng: random.Random, d: bytes) -> bytes:
    lines = d.split(b"\n")
    if lines:
        del lines[rng.randrange(len(lines))]
    return b"\n".join(lines)


def edge_value(rng: random.Random, d: bytes) -> bytes:
    # replace a number with a value at the edge of what parsers handle
    b = bytearray(d)
    digits = [i for i, c in enumerate(b) if chr(c).isdigit()]
    if not digits:
        return d
    i = rng.choice(digits)
    value = rng.choice(
        (b"1e400", b"-1e400", b"nan", b".inf", b"-.inf", b"1e-320", b"99999999999999999999999",
         b"-0", b"0x10", b"1_000", b"~", b"null", b"[]", b"{}", b"true", b"2026-01-01", b"1e16")
    )  # fmt: skip
    return bytes(b[:i] + value + b[i + 1 :])


def nest(rng: random.Random, d: bytes) -> bytes:
    depth = rng.choice((50, 1500))
    return d + b"\nextra: " + b"[" * depth + b"]" * depth + b"\n"


def alias_bomb(rng: random.Random, d: bytes) -> bytes:
    lines = [b"a: &a [x, x, x, x, x, x, x, x, x, x]"]
    for k in range(1, 9):
        prev = chr(ord("a") + k - 1).encode()
        name = chr(ord("a") + k).encode()
        lines.append(name + b": &" + name + b" [" + b", ".join([b"*" + prev] * 10) + b"]")
    return b"\n".join(lines) + b"\n" + d


def tag(rng: random.Random, d: bytes) -> bytes:
    return rng.choice((b"!!python/object:os.system ls\n", b"x: !!binary AAAA\n", b"--- !foo\n")) + d


def blow_up(rng: random.Random, d: bytes) -> bytes:
    lines = d.split(b"\n")
    keep = lines[:1] + lines[1:] * rng.choice((3, 8))
    return b"\n".join(keep)


MUTATIONS: list[Mutation] = [
    flip, set_byte, truncate, utf16, latin1, bom, binary, long_line, swap_lines,
    drop_line, edge_value, edge_value, edge_value, nest, alias_bomb, tag, blow_up,
]  # fmt: skip


@pytest.fixture(scope="module")
def seeds(tmp_path_factory: pytest.TempPathFactory) -> Seeds:
    d = tmp_path_factory.mktemp("seeds")
    sensor = KeyStore.create(d / "rsu-1", "sensor")

    def key_file(path: Path) -> object:
        # a key directory whose sign.key is the mutated file
        store = d / "keydir"
        if store.exists():
            shutil.rmtree(store)
        shutil.copytree(sensor.path, store)
        (store / "sign.key").write_bytes(path.read_bytes())
        (store / "sign.key").chmod(0o600)
        return KeyStore.open(store).signer()

    angles = d / "angles.csv"
    angles.write_text("time_s,angle_deg\n" + "".join(f"{1.7e9 + i},{i - 90}\n" for i in range(40)))
    backend = b"association: {window_s: 0.5, epoch_s: 60}\ntracker: {accel_sigma_mps2: 3.0}\n"
    vehicle = b"x_m: 0\ny_m: -40\nheading_deg: 0\nspeed_mps: 12\n"
    return {
        "calibration": ((REPO / "calibration/example_cal.yaml").read_bytes(), load_calibration),
        "scenario": ((REPO / "examples/crossing.yaml").read_bytes(), load_scenario),
        "samples": (_head(REPO / "calibration/example_turntable_check.csv"), read_samples_csv),
        "angle log": (angles.read_bytes(), read_angle_log),
        "key card": ((sensor.path / "identity.yaml").read_bytes(), KeyCard.load),
        "PEM key": ((sensor.path / "sign.key").read_bytes(), key_file),
        "backend config": (backend, load_backend_config),
        "vehicle": (vehicle, load_vehicle),
    }  # fmt: skip


def _head(path: Path, size: int = 6000) -> bytes:
    """The first whole lines of ``path``, about ``size`` bytes."""
    data = path.read_bytes()[:size]
    return data[: data.rfind(b"\n") + 1]


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


@pytest.mark.fuzz
def test_mutated_text_inputs_give_one_line_errors(seeds: Seeds, tmp_path: Path) -> None:
    rng = random.Random(20261124)
    outcomes: Counter[str] = Counter()
    for name, (seed, load) in seeds.items():  # the seeds themselves are valid
        path = tmp_path / f"seed-{name.replace(' ', '_')}"
        path.write_bytes(seed)
        load(path)
    start_mb = _rss_mb()
    names = sorted(seeds)
    for case in range(CASES):
        name = names[case % len(names)]
        seed, load = seeds[name]
        data = seed
        for _ in range(rng.choice((1, 1, 2, 3))):
            data = rng.choice(MUTATIONS)(rng, data)
        path = tmp_path / f"case-{name.replace(' ', '_')}"
        path.write_bytes(data)
        try:
            load(path)
        except RfsasError as err:
            message = str(err)
            assert message and "\n" not in message.strip(), (name, case, message)
            assert "Traceback" not in message
            outcomes[f"{name}: error"] += 1
        except Exception as err:  # pragma: no cover - the failure being tested for
            pytest.fail(f"{name}, case {case}: {type(err).__name__}: {err!s:.300}")
        else:
            outcomes[f"{name}: ok"] += 1
    growth = _rss_mb() - start_mb
    assert growth < MAX_GROWTH_MB, f"resident size grew {growth:.0f} MB"
    # every input saw errors (the mutations reach the checks)
    for name in names:
        assert outcomes[f"{name}: error"] > 0, outcomes
