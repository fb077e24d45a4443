"""Long simulations report progress: ``sim evaluate`` per episode, ``plan`` a status line."""

from __future__ import annotations

import json

import pytest
from clihelp import run


def test_evaluation_reports_every_episode() -> None:
    pytest.importorskip("gymnasium", reason="needs the sim extra: pip install 'rfsas-hw[sim]'")
    from rfsas_hw.envs import rl

    calls: list[tuple[int, int]] = []
    rows = rl.evaluate(
        [rl.RulePolicy(0.01), rl.RulePolicy(1.0)],
        [30.0, 40.0],
        2,
        progress=lambda done, total: calls.append((done, total)),
    )
    assert len(rows) == 4
    assert calls == [(k, 8) for k in range(1, 9)]


def test_plan_still_prints_one_json_object(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(["plan", "--trials", "50", "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["trials"] == 50
