"""Silicon Labs' AoA locator host's IQ report messages: the payload and topic as the
host writes them, bad messages, fuzzing, and a real broker on loopback end to end."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import random
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
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
from rfsas_hw.link.mqtt import MqttEndpoint, MqttTransport
from rfsas_hw.link.topics import Route
from rfsas_hw.records import ObservationBatch
from rfsas_hw.sources import open_source
from rfsas_hw.sources.ble_iq import ble_channel_mhz
from rfsas_hw.sources.ble_iq_silabs import (
    address_id,
    encode_iq_json,
    id_key,
    parse_iq_json,
    parse_message,
    report_topic,
    split_topic,
)

REPO = Path(__file__).resolve().parents[2]
_load_commands()

# aoa_serialize_iq_report: cJSON_Print of {channel, rssi, sequence, samples}, formatted
# (a tab after each colon, one member per line, the array on one line with ", ")
PAYLOAD = (
    b'{\n\t"channel":\t17,\n\t"rssi":\t-60,\n\t"sequence":\t42,\n'
    b'\t"samples":\t[10, 0, 9, 3, 7, 6, 4, 9, 0, 10, -3, 9, -7, 6, -9, 3, -128, -128]\n}'
)
TOPIC = "silabs/aoa/iq_report/ble-pd-0C4314F4634A/ble-sr-C01122334455"


def test_payload_vector() -> None:
    r = parse_iq_json(PAYLOAD, "v", slot_us=1)
    assert (r.channel_index, r.rssi_dbm, r.event_counter, r.slot_us) == (17, -60.0, 42, 1)
    assert len(r.iq) == 9 and r.iq[0] == 10 + 0j and r.iq[5] == -3 + 9j
    assert np.isnan(r.iq[8])  # -128 is taken as clipped, not used
    assert encode_iq_json(r) == PAYLOAD


def test_topic_and_ids() -> None:
    assert split_topic(TOPIC) == ("ble-pd-0C4314F4634A", "ble-sr-C01122334455")
    assert id_key("ble-sr-C01122334455") == 0xC01122334455
    assert address_id(0x0C4314F4634A, random=False) == "ble-pd-0C4314F4634A"
    assert report_topic("a", "b") == "silabs/aoa/iq_report/a/b"
    msg = parse_message(TOPIC, PAYLOAD)
    assert msg.locator == "ble-pd-0C4314F4634A" and msg.key == 0xC01122334455


@pytest.mark.parametrize(
    ("payload", "message"),
    [
        (b"{", "not JSON"),
        (b"[1, 2]", "a JSON object expected"),
        (PAYLOAD.replace(b'"rssi"', b'"rsi"'), "'rssi' must be a whole number"),
        (PAYLOAD.replace(b"17,", b"true,"), "'channel' must be a whole number"),
        (PAYLOAD.replace(b"17,", b"45,"), "channel 45 outside 0…39"),
        (PAYLOAD.replace(b"42,", b"70000,"), "sequence 70000 outside"),
        (PAYLOAD.replace(b", -128]", b"]"), "17 sample values: I and Q pairs"),
        (PAYLOAD.replace(b"[10, 0, 9, 3, ", b"["), "7 samples: 9…127"),
        (PAYLOAD.replace(b"-7, 6", b"-7, 600"), "whole numbers in -128…127"),
        (PAYLOAD.replace(b"[10", b"[1.5"), "whole numbers in -128…127"),
        (b"\xff\xfe{}", "not JSON"),
        (b" " * 20_000, "payload of 20000 bytes"),
    ],
)
def test_bad_payloads_fail_cleanly(payload: bytes, message: str) -> None:
    with pytest.raises(CaptureFormatError, match=message):
        parse_message(TOPIC, payload)


@pytest.mark.parametrize(
    "topic",
    [
        "silabs/aoa/angle/ble-pd-0C4314F4634A/ble-sr-C01122334455",
        "silabs/aoa/iq_report/ble-sr-C01122334455",
        "silabs/aoa/iq_report/loc/ble-xx-C01122334455",
    ],
)
def test_bad_topics_fail_without_echoing_the_address(topic: str) -> None:
    with pytest.raises(CaptureFormatError) as info:
        parse_message(topic, PAYLOAD)
    assert "c01122334455" not in str(info.value).lower()


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=300))
def test_fuzz_payload_bytes(data: bytes) -> None:
    with contextlib.suppress(CaptureFormatError):
        parse_iq_json(data, "fuzz")


def test_fuzz_mutated_payloads() -> None:
    rng = random.Random(20261127)
    for _ in range(3000):
        b = bytearray(PAYLOAD)
        for _ in range(rng.choice((1, 2, 4))):
            at = rng.randrange(len(b))
            if rng.random() < 0.5:
                b[at] = rng.choice(b'0123456789-,:[]{}" \t\nae.\x00\xff')
            else:
                del b[at : at + rng.randrange(1, 8)]
        try:
            r = parse_iq_json(bytes(b), "fuzz")
        except CaptureFormatError:
            continue
        assert 9 <= len(r.iq) <= 127 and 0 <= r.channel_index <= 39


@settings(max_examples=100, deadline=None)
@given(
    st.integers(0, 39),
    st.integers(-128, 127),
    st.integers(0, 65535),
    st.integers(9, 127),
    st.integers(0, 2**32 - 1),
)
def test_round_trip(channel: int, rssi: int, seq: int, count: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    iq = rng.integers(-127, 128, count) + 1j * rng.integers(-127, 128, count)
    r = dataclasses.replace(parse_iq_json(PAYLOAD, "v"), iq=iq)
    r = dataclasses.replace(r, channel_index=channel, rssi_dbm=float(rssi), event_counter=seq)
    back = parse_iq_json(encode_iq_json(r), "rt")
    assert (back.channel_index, back.rssi_dbm, back.event_counter) == (channel, rssi, seq)
    np.testing.assert_array_equal(back.iq, iq)
    assert json.loads(encode_iq_json(r))["samples"][:2] == [iq[0].real, iq[0].imag]


# --- a real mosquitto on loopback -------------------------------------------------

MOSQUITTO = shutil.which("mosquitto") or (
    "/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None
)


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[int]:
    if MOSQUITTO is None:
        pytest.skip("mosquitto is not installed (Debian package mosquitto)")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    conf = tmp_path / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\n")
    log = (tmp_path / "mosquitto.log").open("wb")
    proc = subprocess.Popen([MOSQUITTO, "-c", str(conf)], stdout=log, stderr=log)
    try:
        deadline = time.monotonic() + 10
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                break
            except OSError:
                if time.monotonic() > deadline or proc.poll() is not None:
                    pytest.fail("mosquitto did not start")
                time.sleep(0.05)
        yield port
    finally:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        log.close()


def _read(src, want: int, limit_s: float = 60.0) -> ObservationBatch:  # type: ignore[no-untyped-def]
    got: list[ObservationBatch] = []
    deadline = time.monotonic() + limit_s
    while sum(len(b) for b in got) < want and time.monotonic() < deadline:
        batch = src.read(0.2)
        if batch is not None and len(batch):
            got.append(batch)
    return ObservationBatch.concat(got) if got else ObservationBatch.empty(8)


FREQ_CH = 17
UCA = ArrayGeometry.uca(8, 0.6 * C_MPS / (ble_channel_mhz(FREQ_CH) * 1e6))


def test_emulated_locator_host_through_a_broker(broker: int, tmp_path: Path) -> None:
    url = f"mqtt://127.0.0.1:{broker}"
    with open_source(f"bleiq+mqtt://127.0.0.1:{broker}?elements=8") as src:
        result = CliRunner().invoke(
            cli,
            ["aoa", "emulate", "bleiq", "--mqtt", url, "--packets", "200", "--seed", "6"],
            catch_exceptions=False,
        )
        assert result.exit_code == 0, result.output
        batch = _read(src, 200)
        stats = src.stats.as_dict()
    theta = np.random.default_rng(6).uniform(-180.0, 180.0, 200)  # the command's draws
    assert len(batch) == 200 and not stats["skipped"], stats
    assert set(batch.mac.tolist()) == {0xC01122334455}
    assert batch.csi is not None and batch.csi.h.shape[2] == 9  # 74 1-µs slots: 9 passes
    base = load_calibration(REPO / "calibration" / "example_cal.yaml")
    ideal = ElementCalibration(np.zeros(8), np.zeros(8))
    cal = dataclasses.replace(base, array=ArrayCalibration(UCA, ideal, ble_channel_mhz(FREQ_CH)))
    mono = estimate(cal, batch.rssi_dbm[:, 0], batch.rssi_dbm[:, 1], batch.channel)
    res = array_df_result(cal, batch, mono)
    v = res.valid
    assert v.mean() > 0.98
    err = (res.angle_deg[v] - theta[v] + 180.0) % 360.0 - 180.0
    crb = crb_deg(UCA, theta[v], 25.0, ble_channel_mhz(FREQ_CH), snapshots=9)
    rms, bound = float(np.sqrt(np.mean(err**2))), float(np.sqrt(np.mean(crb**2)))
    assert rms <= 1.2 * bound, (rms, bound)
    assert "c01122334455" not in repr(stats).lower()


def test_bad_messages_and_other_locators_are_counted(broker: int) -> None:
    pub = MqttTransport(MqttEndpoint("127.0.0.1", broker), "send")
    with open_source(f"bleiq+mqtt://127.0.0.1:{broker}?elements=3") as src:
        try:
            good = parse_iq_json(PAYLOAD, "v")
            good = dataclasses.replace(good, iq=np.tile([20 + 5j, 19 + 8j, 17 + 11j], 5))
            pub.publish(Route(TOPIC), encode_iq_json(good))
            pub.publish(Route(TOPIC), b"not json")
            pub.publish(Route(TOPIC.replace("0C43", "FFFF")), encode_iq_json(good))
            pub.publish(Route(TOPIC.replace("ble-sr-", "tag-")), encode_iq_json(good))
            pub.publish(Route(TOPIC), encode_iq_json(good))
        finally:
            pub.close()
        batch = _read(src, 2, limit_s=20.0)
        deadline = time.monotonic() + 10
        while sum(src.stats.skipped.values()) < 3 and time.monotonic() < deadline:
            src.read(0.2)
        stats = src.stats
    assert len(batch) == 2
    assert stats.skipped["bad_report"] == 2 and stats.skipped["other_locator"] == 1
    assert all("c01122334455" not in e.lower() for e in stats.errors)


def test_no_broker_is_a_clear_error() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    with pytest.raises(SourceError, match=f"bleiq\\+mqtt://127.0.0.1:{port}"):
        open_source(f"bleiq+mqtt://127.0.0.1:{port}?elements=8&connect_s=1")
    with pytest.raises(SourceError, match="HOST"):
        open_source("bleiq+mqtt:broker?elements=8")
    with pytest.raises(SourceError, match="slot 3"):
        open_source("bleiq+mqtt://127.0.0.1?elements=8&slot=3")
