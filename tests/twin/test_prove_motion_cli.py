"""``rfsas replay`` on a fixed mount: the corner AP behind rsu-nw in the bundled crossing,
from the twin's capture to bearings, with the motion rule (the default) and without it
(``--prove-motion 0``, ``--moving-mount``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.twin.capture_writer import card_records, write_capture
from rfsas_hw.twin.scenario import load_scenario
from rfsas_hw.twin.world import World

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
_load_commands()


def test_replay_of_a_fixed_mount_drops_the_static_ap_behind(tmp_path: Path) -> None:
    scenario = load_scenario(EXAMPLES / "crossing.yaml")
    world = World(scenario)
    rec = world.receptions("rsu-nw")
    capture = tmp_path / "rsu-nw.pcap"
    write_capture(capture, card_records(world, rec, 0), "pcap")
    ap = [e.id for e in scenario.spec.emitters].index("corner-ap")
    truth = {int(t) // 1000: i for i, t in enumerate(rec.capture_ns[:, 0])}

    def run(*extra: str) -> tuple[int, int, int]:
        out = tmp_path / ("_".join(extra).replace("-", "") or "default")
        out = out.with_suffix(".jsonl")
        result = CliRunner().invoke(
            cli,
            [
                *("replay", str(capture), "--pose", "-9,9,140", "--out", str(out)),
                *("--calibration", str(EXAMPLES / "calibration" / "rsu-nw.yaml"), *extra),
            ],
            catch_exceptions=False,
        )
        assert result.exit_code == 0, result.output
        rows = [json.loads(line) for line in out.read_text().splitlines()]
        idx = np.array([truth[int(b["t_ns"]) // 1000] for b in rows])
        err = (np.array([b["azimuth_deg"] for b in rows]) - rec.true_azimuth_deg[idx] + 180) % 360
        wrong = np.abs(err - 180.0) > 3.0 * np.array([b["sigma_deg"] for b in rows])
        return len(rows), int(np.sum(rec.emitter[idx] == ap)), int(wrong.sum())

    total, from_ap, wrong = run("--prove-motion", "0")
    assert from_ap > 50 and wrong >= from_ap  # every bearing of the AP is confident-wrong
    assert run("--moving-mount") == (total, from_ap, wrong)  # no motion rule either
    total, from_ap, wrong = run()  # a fixed mount: the motion rule by default
    assert from_ap == 0 and total > 40
    assert wrong <= 0.05 * total
    assert run("--moving-mount", "--prove-motion", "3") == (total, from_ap, wrong)
