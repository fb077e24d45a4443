"""A shared nonce secret: same ids across sensors, unlinkable epochs, private file."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
from privhelp import CALIBRATION, STILL, write_known_capture

from rfsas_hw.errors import KeyStoreError
from rfsas_hw.privacy import DerivedNonces, MacHasher, hash_mac, write_secret


def test_derived_nonces_differ_per_epoch_and_per_secret() -> None:
    a, b = DerivedNonces(b"s" * 32), DerivedNonces(b"t" * 32)
    assert a.nonce_for(7) == DerivedNonces(b"s" * 32).nonce_for(7)
    assert a.nonce_for(7) != a.nonce_for(8)
    assert a.nonce_for(7) != b.nonce_for(7)
    mac = 0x3C22FB0102AB
    assert hash_mac(a.nonce_for(7), mac) != hash_mac(a.nonce_for(8), mac)
    with pytest.raises(ValueError, match="at least 16 bytes"):
        DerivedNonces(b"short")


def test_secret_file_is_private_and_never_overwritten(tmp_path: Path) -> None:
    path = tmp_path / "secret.bin"
    write_secret(path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and len(path.read_bytes()) == 32
    with pytest.raises(KeyStoreError, match="refusing to overwrite"):
        write_secret(path)
    hasher = MacHasher(DerivedNonces.from_file(path))
    assert hasher.hash_one(1, 0) == hasher.hash_one(1, 10)
    os.chmod(path, 0o644)
    with pytest.raises(KeyStoreError, match="readable by others; chmod 600"):
        DerivedNonces.from_file(path)


def _ids(capture: Path, out: Path, *extra: str) -> set[str]:
    cmd = [sys.executable, "-m", "rfsas_hw.cli.main", "replay", str(capture)]
    cmd += [*STILL, "--calibration", str(CALIBRATION), "--out", str(out), *extra]
    proc = subprocess.run(cmd, capture_output=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    return {json.loads(line)["emitter"] for line in out.read_text().splitlines()}


def test_two_replays_with_one_secret_agree_on_ids(tmp_path: Path) -> None:
    capture = tmp_path / "known.pcap"
    write_known_capture(capture, time.time_ns())
    secret = tmp_path / "secret.bin"
    subprocess.run(
        [sys.executable, "-m", "rfsas_hw.cli.main", "nonces", "secret", "-o", str(secret)],
        check=True,
        capture_output=True,
    )
    shared = ("--nonce-secret", str(secret))
    first = _ids(capture, tmp_path / "a.jsonl", *shared)
    second = _ids(capture, tmp_path / "b.jsonl", *shared)
    unshared = _ids(capture, tmp_path / "c.jsonl")
    assert first and first == second
    assert not first & unshared
