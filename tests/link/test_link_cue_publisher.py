"""The cue publisher: a roadside unit's bearings become rate-limited signed cues."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np
from click.testing import CliRunner
from linkhelp import NOW_NS, SCHEDULE, Kept

from rfsas_hw.cli.linkopts import make_cue_publisher, send_options
from rfsas_hw.link import Signer, TrustedKeys
from rfsas_hw.link.cue import CueKind, decode_cue
from rfsas_hw.link.cue_publisher import CuePublisher
from rfsas_hw.link.cue_receiver import CueReceiver, CueReceiverConfig
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.transport import open_transport
from rfsas_hw.records import BearingBatch, Pose


def batch(t_ns: int, emitters: list[int], channel: int = 11) -> BearingBatch:
    n = len(emitters)
    return BearingBatch(
        sensor_id="rsu-1",
        t_ns=np.full(n, t_ns, np.int64),
        azimuth_deg=np.full(n, 359.99999),
        sigma_deg=np.full(n, 2.0),
        snr_db=np.full(n, 20.0),
        channel=np.full(n, channel, np.int16),
        emitter=np.array(emitters, np.uint64),
    )


def test_one_cue_per_emitter_per_interval_and_each_verifies(
    signer: Signer, trust: TrustedKeys
) -> None:
    link = Kept()
    t0 = NOW_NS - 900_000_000
    pub = CuePublisher(
        signer, link, Pose(5.0, 6.0, 90.0), every_s=0.5, valid_s=2.0,
        epoch_s=SCHEDULE.epoch_s, clock=lambda: NOW_NS - 50_000_000,
    )  # fmt: skip
    pub.on_bearings(batch(t0, [11, 22]))
    pub.on_bearings(batch(t0 + 100_000_000, [11, 22]))  # too soon: skipped
    pub.on_bearings(batch(t0 + 600_000_000, [11]))
    pub.on_bearings(batch(t0 + 600_000_000, [33], channel=20))  # not a Wi-Fi channel
    assert pub.stats.as_dict() == {"cues": 3, "skipped.not_wifi": 1, "skipped.rate": 2}
    cues = [decode_cue(d) for d in link.sent]
    assert [c.emitter for c in cues] == [11, 22, 11]
    assert len({c.seq for c in cues}) == 3
    c = cues[0]
    assert c.kind is CueKind.BEARING and c.channel == 11 and (c.x_m, c.y_m) == (5.0, 6.0)
    assert c.a == 0.0  # 359.99999 wraps to 0 on the compass in float32
    assert c.valid_until_us - c.t_obs_us == 2_000_000
    rx = CueReceiver(trust, CueReceiverConfig(epoch_s=SCHEDULE.epoch_s, grace_s=SCHEDULE.grace_s))
    assert all(rx.feed(d, NOW_NS) is not None for d in link.sent)


def test_send_cues_option_builds_a_cue_publisher(tmp_path: Path) -> None:
    sensor = KeyStore.create(tmp_path / "rsu-7", "sensor")
    listener = open_transport("udp://127.0.0.1:0", "recv")
    host, port = listener.address  # type: ignore[attr-defined]

    @click.command()
    @send_options
    def cmd(send: str | None, keys_dir: Path | None) -> None:
        pub = make_cue_publisher(keys_dir, Pose(0, 0, 0))
        assert pub is not None
        pub.on_bearings(batch(NOW_NS, [7]))
        pub.close()

    try:
        args = ["--send-cues", f"udp://{host}:{port}", "--keys", str(sensor.path)]
        result = CliRunner().invoke(cmd, args)
        assert result.exit_code == 0, result.output
        datagram = listener.recv(1.0)
        assert datagram is not None and decode_cue(datagram).sender_id == "rsu-7"
    finally:
        listener.close()

    @click.command()
    @send_options
    def nokeys(send: str | None, keys_dir: Path | None) -> None:
        make_cue_publisher(keys_dir, Pose(0, 0, 0))

    result = CliRunner().invoke(nokeys, ["--send-cues", "udp://127.0.0.1:9"])
    assert "--send-cues needs --keys" in str(result.exception)
