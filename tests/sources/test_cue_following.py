"""Tunable sources follow a cue within one dwell: Wi-Fi (a fake ``iw``), the DF board
emulator (its scan-plan command), and the twin's virtual source."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.board.emulator import BoardEmulator, Emitter, Scenario
from rfsas_hw.board.transport import EmulatorRunner, PtyEndpoint
from rfsas_hw.link.cue import Cue, CueKind, Phy, band_of, sign_cue
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.signing import Signer
from rfsas_hw.link.transport import open_transport
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.sources.schedule import ChannelCue, CueScheduler, SchedulerConfig
from rfsas_hw.sources.serial_board import SerialSource
from rfsas_hw.sources.virtual import VirtualSource
from rfsas_hw.sources.wifi import ChannelHopper, ScanPlan, WifiSource
from rfsas_hw.studies.cueing import CAR, PLAN_13, CueingConfig, cueing_scenario


@pytest.fixture
def fake_iw(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An ``iw`` on PATH that records its arguments, one call a line."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    calls = tmp_path / "iw-calls.txt"
    fake = bin_dir / "iw"
    fake.write_text(f'#!/bin/sh\necho "$@" >> {calls}\n')
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}:{os.environ.get('PATH', '')}")
    return calls


def test_hopper_runs_iw_for_the_cued_channel_at_the_next_tick(fake_iw: Path) -> None:
    clock = [50.0]
    plan = ScanPlan((1, 6, 11), 0.2)
    sched = CueScheduler(plan.channels, plan.dwell_s, SchedulerConfig(cue_dwell_s=0.5))
    hopper = ChannelHopper("mon0", plan, clock=lambda: clock[0], scheduler=sched)
    seen = []
    for k in range(10):
        if k == 3:  # mid-dwell of channel 1 (second lap): a cue for channel 44 arrives
            clock[0] += 0.05
            sched.offer(ChannelCue(5, 44, 0.8, hopper.now_s() + 2.0), hopper.now_s())
            # the select wakes at least once a plan dwell, even during a longer cue dwell
            assert hopper.next_hop_in() == pytest.approx(0.2)
        hopper.tick()
        seen.append(hopper.current)
        clock[0] += min(hopper.next_hop_in(), 0.2)
    lines = fake_iw.read_text().splitlines()
    assert lines[3] == "dev mon0 set channel 44"  # the first command after the cue
    # then the rest of channel 1's dwell, and the plan goes on
    assert [ln.rsplit(" ", 1)[1] for ln in lines[:6]] == ["1", "6", "11", "44", "1", "6"]
    assert seen[3:6] == [44, 44, 44]
    assert sched.stats.obeyed == 1


def _veth() -> tuple[str, str]:
    a, b = f"rfc{os.getpid() % 10000}", f"rfd{os.getpid() % 10000}"
    try:
        subprocess.run(
            ["ip", "link", "add", a, "type", "veth", "peer", "name", b],
            check=True,
            capture_output=True,
        )
    except (OSError, subprocess.CalledProcessError) as err:
        pytest.skip(f"cannot create a veth pair here (needs root/CAP_NET_ADMIN): {err}")
    for name in (a, b):
        with contextlib.suppress(OSError):
            Path(f"/proc/sys/net/ipv6/conf/{name}/disable_ipv6").write_text("1")
        subprocess.run(["ip", "link", "set", name, "up"], check=True)
    return a, b


@pytest.fixture
def veth() -> Iterator[str]:
    a, _ = _veth()
    try:
        yield a
    finally:
        subprocess.run(["ip", "link", "del", a], check=False, capture_output=True)


def test_wifi_source_follows_a_cue_within_one_dwell(veth: str, fake_iw: Path) -> None:
    dwell = 0.3
    with WifiSource(
        veth, channels=[1, 6, 11], dwell_s=dwell, any_link_type=True, cues=SchedulerConfig()
    ) as src:
        src.read(0.05)
        assert src.scheduler is not None
        # the scheduler serves a cue at once when its airtime budget is free: the
        # source tunes at its first read after the offer (counted in reads, not
        # judged against the wall clock)
        src.scheduler.offer(ChannelCue(9, 149, 0.9, src.now_s() + 2.0), src.now_s())
        src.read(0.01)
        assert f"dev {veth} set channel 149" in fake_iw.read_text(), "cue not followed"
        assert src.stats.extra["cues_obeyed"] == 1


@pytest.fixture
def board(tmp_path: Path) -> Iterator[tuple[BoardEmulator, str]]:
    emu = BoardEmulator(
        Scenario([Emitter(bearing_deg=10.0, distance_m=15.0, channel=11, rate_hz=50.0)], seed=3)
    )
    ep = PtyEndpoint(tmp_path / "ttyCUE")
    runner = EmulatorRunner(emu, ep).start()
    try:
        yield emu, ep.path
    finally:
        runner.stop()


def _tuned_mhz(emu: BoardEmulator) -> int:
    return int(emu.tuned(np.array([emu.board_us()], np.int64))[0])


def test_serial_board_follows_a_cue_within_one_dwell(board: tuple[BoardEmulator, str]) -> None:
    emu, path = board
    dwell_ms = 250
    with SerialSource(
        path, channels=[1, 6, 36], dwell_ms=dwell_ms, cues=SchedulerConfig(cue_dwell_s=0.6)
    ) as src:
        src.read(0.05)
        assert src.scheduler is not None
        t_offer = time.monotonic()
        src.scheduler.offer(ChannelCue(1, 11, 0.9, src.now_s() + 2.0), src.now_s())
        src.read(0.01)  # the new plan goes to the board at the first read after the offer
        deadline = t_offer + 30.0  # the emulator applies it on its own thread
        while _tuned_mhz(emu) != 2462:
            assert time.monotonic() < deadline, "board not on the cued channel"
            src.read(0.01)
        # it hears the emitter on the cued channel, then the plan comes back
        heard = 0
        while time.monotonic() - t_offer < 0.55:
            b = src.read(0.02)
            heard += 0 if b is None else int((b.channel == 11).sum())
        assert heard > 0
        end = time.monotonic() + 0.5
        while _tuned_mhz(emu) == 2462 and time.monotonic() < end:
            src.read(0.02)
        assert _tuned_mhz(emu) in (2412, 2437, 5180)
        assert src.stats.extra["cues_obeyed"] == 1


def test_virtual_source_follows_a_cue_within_one_dwell() -> None:
    sc = cueing_scenario(4, PLAN_13, CueingConfig(duration_s=6.0), phone_channel=9, offset_s=0.0)
    with VirtualSource(sc, CAR, cues=SchedulerConfig(cue_dwell_s=1.0), batch_s=0.1) as src:
        assert src.scheduler is not None
        before = [b for b in (src.read() for _ in range(20)) if b is not None]
        t_cue = src.now_s()
        src.scheduler.offer(ChannelCue(1, 9, 0.9, t_cue + 1.0), t_cue)
        during = [b for b in (src.read() for _ in range(10)) if b is not None]
        after = [b for b in (src.read() for _ in range(10)) if b is not None]
    t0 = src.world.t0_ns
    frames = [
        (float((t - t0) / 1e9), int(c))
        for b in during
        for t, c in zip(b.t_ns, b.channel, strict=True)
    ]
    # everything heard during the dwell is on the cued channel, and the phone's bursts are heard
    assert frames and all(c == 9 for _, c in frames)
    assert min(t for t, _ in frames) - t_cue < 0.6  # its next burst (every 0.5 s ± 50 ms)
    for b in before + after:
        t = (b.t_ns - t0) / 1e9
        tl = src.scheduler.timeline(6.0)
        assert (tl.channel_at(t) == b.channel).all()
    assert src.stats.extra["cues_obeyed"] == 1


def test_live_command_obeys_signed_cues_from_the_link(
    veth: str, fake_iw: Path, tmp_path: Path, cal_path: Path
) -> None:
    """``rfsas live --channels … --cues URL --keys DIR``: a cue from an enrolled roadside
    unit moves the interface to the cued channel; a forged one does not."""
    vehicle = KeyStore.create(tmp_path / "obu", "sensor")
    rsu = KeyStore.create(tmp_path / "rsu-1", "sensor")
    vehicle.trust.enroll(rsu.card)
    signer = rsu.signer()
    forger = Signer(signer.sender_id, ec.generate_private_key(ec.SECP256R1()))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(
        [sys.executable, "-m", "rfsas_hw.cli.main", "live", f"wifi:{veth}", "--any-link-type",
         "--channels", "1,6,11", "--dwell", "0.2", "--duration", "2.5",
         "--cues", f"udp://127.0.0.1:{port}", "--keys", str(vehicle.path),
         "--calibration", str(cal_path), "--out", str(tmp_path / "b.jsonl")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    out = open_transport(f"udp://127.0.0.1:{port}", "send")
    try:
        # the cue socket opens just before the run starts hopping
        deadline = time.monotonic() + 20.0
        while not (fake_iw.exists() and len(fake_iw.read_text().splitlines()) >= 2):
            assert time.monotonic() < deadline and proc.poll() is None, "live did not start"
            time.sleep(0.05)
        for seq, (who, channel) in enumerate([(forger, 40), (signer, 149), (forger, 44)]):
            t_us = time.time_ns() // 1000
            cue = Cue(
                sender_id=who.sender_id, t_gen_us=t_us, seq=seq,
                epoch=EpochSchedule().epoch_of(t_us * 1000), emitter=7, t_obs_us=t_us,
                valid_until_us=t_us + 1_000_000, channel=channel, band=band_of(channel),
                phy=Phy.UNKNOWN, kind=CueKind.BEARING, risk=0.9, x_m=0.0, y_m=0.0, a=10.0, b=2.0,
            )  # fmt: skip
            out.send(sign_cue(who, cue))
        _, stderr = proc.communicate(timeout=60)
    finally:
        out.close()
        if proc.poll() is None:
            proc.kill()
    # no frames are injected, so the run reports 0 bearings (exit 1); it must not crash
    assert proc.returncode in (0, 1) and "Traceback" not in stderr, stderr
    lines = fake_iw.read_text().splitlines()
    assert f"dev {veth} set channel 149" in lines
    assert not any(line.endswith((" 40", " 44")) for line in lines)


def test_live_command_takes_channels_and_cues_for_a_serial_board(
    board: tuple[BoardEmulator, str], tmp_path: Path, cal_path: Path
) -> None:
    """``rfsas live serial:… --channels … --cues URL --keys DIR`` sets the board's scan plan
    and follows cues, as the serial driver does (cueing.md); a signed cue retunes it."""
    emu, path = board
    vehicle = KeyStore.create(tmp_path / "obu", "sensor")
    rsu = KeyStore.create(tmp_path / "rsu-1", "sensor")
    vehicle.trust.enroll(rsu.card)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(
        [sys.executable, "-m", "rfsas_hw.cli.main", "live", f"serial:{path}",
         "--channels", "1,6,36", "--dwell", "0.25", "--duration", "4",
         "--cues", f"udp://127.0.0.1:{port}", "--keys", str(vehicle.path),
         "--calibration", str(cal_path), "--out", str(tmp_path / "b.jsonl")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    out = open_transport(f"udp://127.0.0.1:{port}", "send")
    try:
        deadline = time.monotonic() + 20.0
        while _tuned_mhz(emu) not in (2412, 2437, 5180):  # the plan is running
            assert time.monotonic() < deadline and proc.poll() is None, "live did not start"
            time.sleep(0.05)
        heard = False
        while not heard and time.monotonic() < deadline and proc.poll() is None:
            t_us = time.time_ns() // 1000
            cue = Cue(
                sender_id="rsu-1", t_gen_us=t_us, seq=int(t_us % 1_000_000),
                epoch=EpochSchedule().epoch_of(t_us * 1000), emitter=7, t_obs_us=t_us,
                valid_until_us=t_us + 1_000_000, channel=11, band=band_of(11),
                phy=Phy.UNKNOWN, kind=CueKind.BEARING, risk=0.9, x_m=0.0, y_m=0.0, a=10.0, b=2.0,
            )  # fmt: skip
            out.send(sign_cue(rsu.signer(), cue))
            end = time.monotonic() + 0.5
            while time.monotonic() < end and not heard:
                heard = _tuned_mhz(emu) == 2462
                time.sleep(0.01)
        _, stderr = proc.communicate(timeout=60)
    finally:
        out.close()
        if proc.poll() is None:
            proc.kill()
    assert "Traceback" not in stderr and "needs a wifi" not in stderr, stderr
    assert heard, "the board was not retuned to the cued channel 11"
