"""``rfsas aoa emulate`` feeding ``rfsas live ublox:/kraken:`` as a user runs them."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest

from rfsas_hw.cli.main import main
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S
from rfsas_hw.privacy.hashing import DerivedNonces, hash_mac, write_secret
from rfsas_hw.sources.kraken_emulator import KrakenEmulator, KrakenServer, Vfo

REPO = Path(__file__).resolve().parents[2]
TAG = 0xCCF9578E0D8A


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as exc:
        main([*args])
        raise SystemExit(0)
    out = capsys.readouterr()
    return int(exc.value.code or 0), out.out, out.err


def _emulator(*args: str) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "rfsas_hw.cli.main", "aoa", "emulate", *args, "--duration", "30"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=REPO,
    )
    assert proc.stdout is not None
    return proc, proc.stdout.readline().strip()


def _stop(proc: subprocess.Popen[str]) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    if proc.stdout is not None:
        proc.stdout.close()


def test_live_ublox_hashes_tags_with_the_deployment_secret(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    secret, out = tmp_path / "nonce.secret", tmp_path / "b.jsonl"
    write_secret(secret)
    proc, path = _emulator("ublox", "--link", str(tmp_path / "tty"), "--tag", "CCF9578E0D8A,20")
    try:
        time.sleep(0.2)
        code, _, err = run(
            [
                "live",
                f"ublox:{path}#boresight=90",
                "--nonce-secret",
                str(secret),
                "--duration",
                "1.5",
                "--out",
                str(out),
            ],
            capsys,
        )
    finally:
        _stop(proc)
    assert code == 0, err
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) >= 5
    nonces = DerivedNonces.from_file(secret)
    epoch_ns = int(DEFAULT_EPOCH_S * 1e9)
    for row in rows:
        want = hash_mac(nonces.nonce_for(row["t_ns"] // epoch_ns), TAG)
        assert int(row["emitter"], 16) == want
        assert 100 <= row["azimuth_deg"] <= 120
    text = out.read_text().lower()
    assert "ccf9578e0d8a" not in text and str(TAG) not in text


def test_live_kraken_from_the_emulator(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "k.jsonl"
    emulator = KrakenEmulator([Vfo.parse("433.92,45")], torn=0.2)
    server = KrakenServer(emulator, rate_hz=20.0).start()  # in-process: one start-up less
    try:
        code, text, err = run(
            ["live", f"kraken:{server.url}#poll=0.05", "--duration", "1.5", "--out", str(out)],
            capsys,
        )
    finally:
        server.stop()
    assert code == 0, err
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) >= 5
    assert all(35 <= r["azimuth_deg"] <= 55 and r["sigma_deg"] == 5.0 for r in rows)
    assert "polls" in text


def test_bad_emulator_options_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["aoa", "emulate", "ublox", "--tag", "nonsense", "--duration", "0"], capsys)
    assert code == 2 and "MAC,AZIMUTH" in err
    code, _, err = run(["aoa", "emulate", "kraken", "--vfo", "1", "--duration", "0"], capsys)
    assert code == 2 and "FREQ_MHZ,BEARING" in err
    code, _, err = run(
        ["aoa", "emulate", "ublox", "--pty", "--tcp", "0", "--duration", "0"], capsys
    )
    assert code == 2 and "give --pty or --tcp, not both" in err


@pytest.mark.parametrize("unit", ["ublox", "kraken"])
@pytest.mark.parametrize("option", [("--noise", "-1"), ("--rate", "0"), ("--rate", "1e9")])
def test_impossible_emulator_settings_exit_2(
    capsys: pytest.CaptureFixture[str], unit: str, option: tuple[str, str]
) -> None:
    code, _, err = run(["aoa", "emulate", unit, *option, "--duration", "0"], capsys)
    assert code == 2 and option[0] in err and "Traceback" not in err


def test_ublox_emulator_refuses_to_replace_a_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mine = tmp_path / "notes.txt"
    mine.write_text("keep me")
    code, _, err = run(["aoa", "emulate", "ublox", "--link", str(mine), "--duration", "0"], capsys)
    assert code == 2 and "not a pseudo-terminal link" in err
    assert mine.read_text() == "keep me"


def _page_server(status: int, body: bytes) -> tuple[Any, threading.Thread, str]:
    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            self.send_response(status)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format: str, *args: object) -> None:
            pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=httpd.serve_forever, args=(0.05,), daemon=True)
    thread.start()
    return httpd, thread, f"http://127.0.0.1:{httpd.server_address[1]}/DOA_value.html"


def test_kraken_failures_say_what_was_wrong(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Not all "the input held no frames": the unit not reached, an HTTP error, the
    wrong page each end the run with what was wrong."""
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        closed = s.getsockname()[1]
    cases: list[tuple[int | None, bytes, str]] = [
        (None, b"", "nothing was read: http://127.0.0.1:"),
        (404, b"no such page", "nothing was read: http://127.0.0.1:"),
        (200, b"<!DOCTYPE html><html>the web UI</html>", "the page is markup, not CSV"),
    ]
    expected_detail = ["refused", "404", "not_csv"]
    for (status, body, words), detail in zip(cases, expected_detail, strict=True):
        server = None
        if status is None:
            url = f"http://127.0.0.1:{closed}/DOA_value.html"
        else:
            server, thread, url = _page_server(status, body)
        try:
            code, _, err = run(
                ["live", f"kraken:{url}#poll=0.05", "--duration", "0.5",
                 "--out", str(tmp_path / f"k{status}.jsonl"), "--force"],
                capsys,
            )  # fmt: skip
        finally:
            if server is not None:
                server.shutdown()
                thread.join(5)
                server.server_close()
        last = " ".join(err.strip().splitlines()[-1].split())
        assert code == 1, err
        assert "held no frames" not in last, last
        assert words in last and detail in last.lower(), last
