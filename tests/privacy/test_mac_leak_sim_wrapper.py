"""The RF-SAS wrapper's outputs hold no MAC: observations, ``info`` and overlay frames.

A wrapped highway-env episode runs with a truth file (the only place the
bridge writes MACs); every MAC in it is then searched for, in every form
:func:`test_mac_leak.find_leaks` knows, in what the wrapper handed out.
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path
from typing import Any

import pytest
from test_mac_leak import find_leaks

pytest.importorskip(
    "highway_env", reason="needs the highway extra: pip install 'rfsas-hw[highway]'"
)

from rfsas_hw.bridges.bridge import Bridge
from rfsas_hw.bridges.highway import HighwayAdapter, idle_action, make_scene
from rfsas_hw.envs.rfsas_wrapper import RfsasWrapper


def test_wrapper_outputs_hold_no_mac(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    truth = tmp_path / "truth.jsonl"
    real_init = Bridge.__init__

    def with_truth(self: Bridge, *args: Any, **kwargs: Any) -> None:
        kwargs["truth_path"] = truth
        real_init(self, *args, **kwargs)

    monkeypatch.setattr(Bridge, "__init__", with_truth)
    cfg = {"policy_frequency": 5, "initial_vehicle_count": 1, "spawn_probability": 0.0}
    env = RfsasWrapper(
        make_scene("intersection-v0", cfg, render_mode="rgb_array"), HighwayAdapter()
    )
    blobs: dict[str, bytes] = {}
    try:
        obs, info = env.reset(seed=5)
        for k in range(15):
            obs, _, term, trunc, info = env.step(idle_action(env))
            blobs[f"obs{k}"] = pickle.dumps(obs)
            blobs[f"info{k}"] = json.dumps(info["rfsas"], default=str).encode()
            if k % 5 == 4:  # a few overlay frames (each is 1 MB to search)
                blobs[f"frame{k}"] = env.render().tobytes()
            if term or trunc:
                break
    finally:
        env.close()
    macs = [
        int(rec["mac"].replace(":", ""), 16)
        for rec in map(json.loads, truth.read_text().splitlines())
        if rec["record"] == "device"
    ]
    assert macs, "the episode gave no device a MAC: the test would prove nothing"
    assert any(b'"emitter"' in b for name, b in blobs.items() if name.startswith("info"))
    assert find_leaks(blobs, macs) == []
