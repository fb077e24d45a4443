"""``rfsas live`` sending through a broker that is killed and restarted mid-run: the
sensor logs the loss and the recovery, counts the bearings it could not send, goes on,
and, stopped with Ctrl-C, exits 0 (the run did its work; the outage was ridden out)."""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from brokerhelp import Broker, Deployment
from fleethelp import ORIGIN

from rfsas_hw.link import Receiver
from rfsas_hw.privacy.hashing import write_secret

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "cli"))

from clihelp import STILL, rt_writer, write_calibration
from terminal import ctrl_c_as_at_a_terminal


def test_live_rides_out_a_broker_outage(
    broker: Broker, deployment: Deployment, tmp_path: Path
) -> None:
    cal = write_calibration(tmp_path / "cal.yaml")
    secret = tmp_path / "secret.bin"
    write_secret(secret)
    sensor = deployment.sensors["rsu-1"]
    rx = Receiver.listen(broker.url("be-b"), deployment.backends["be-b"].trust)
    proc = subprocess.Popen(
        [sys.executable, "-m", "rfsas_hw.cli.main", "live", "pcap:-", "--calibration", str(cal),
         "--keys", str(sensor.path), "--nonce-secret", str(secret), "--pose", "1,2,90",
         "--send", broker.url("rsu-1", origin=ORIGIN), "--json", *STILL],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        preexec_fn=ctrl_c_as_at_a_terminal,
    )  # fmt: skip
    assert proc.stdin is not None
    stop = threading.Event()

    def feed() -> None:
        assert proc.stdin is not None
        try:
            proc.stdin.write(rt_writer.pcap([])[:24])
            i = 0
            while not stop.is_set() and proc.poll() is None:
                frame = rt_writer.mac80211_header(-50 - i % 5, -51 - i % 3) + rt_writer.dot11(
                    ta=0x0200_0000_0001 + i % 3, seq=i % 4096
                )
                proc.stdin.write(rt_writer.pcap([(time.time_ns(), frame)])[24:])
                proc.stdin.flush()
                i += 1
                stop.wait(0.02)
        except (BrokenPipeError, ValueError):
            pass  # the sensor's --duration is over

    lines: list[str] = []

    def read_log() -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.append(line.decode(errors="replace"))

    feeder = threading.Thread(target=feed)
    feeder.start()
    reader = threading.Thread(target=read_log)
    reader.start()
    try:
        got = 0
        deadline = time.monotonic() + 60
        while not got and time.monotonic() < deadline:
            got = len(rx.receive(0.1))
        assert got, "no message before the outage"
        broker.kill()
        time.sleep(2.0)
        broker.start()
        deadline = time.monotonic() + 60
        while "sending again" not in "".join(lines) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert "sending again" in "".join(lines), "".join(lines)
        proc.send_signal(signal.SIGINT)  # the normal end of a live run
        proc.wait(60)
        assert proc.stdout is not None
        stdout = proc.stdout.read()  # the summary: small, it fits the pipe
    finally:
        stop.set()
        feeder.join(30)
        if proc.poll() is None:
            proc.kill()
            proc.wait(30)
        reader.join(30)
        for pipe in (proc.stdin, proc.stdout, proc.stderr):
            if pipe is not None:
                # stdin: a frame the feeder wrote as the sensor ended stays in the buffer,
                # and closing tries to flush it into the closed pipe (closed all the same)
                with contextlib.suppress(BrokenPipeError):
                    pipe.close()
        rx.close()
    err = "".join(lines)
    assert proc.returncode == 0, err
    assert "lost the broker" in err and "connected to the broker again" in err
    assert "cannot send" in err and "sending again" in err
    summary = json.loads(stdout)
    assert summary["ok"] and summary["failure"] is None
    sent = next(v for k, v in summary["outputs"].items() if k.startswith("send "))
    assert sent["dropped.send_error"] > 0 and sent["sent"] > 0
