"""The sweep runner: the same results with 1 and 2 Dask workers, in the order of the specs."""

from __future__ import annotations

import pytest

from rfsas_hw.errors import ConfigError
from rfsas_hw.ncap.scenarios import Cell
from rfsas_hw.ncap.sweep import configs, run_sweep, specs_for


def test_configurations_expand_rfsas_over_deployments_and_devices() -> None:
    got = configs(["los", "rfsas+los"], ["car", "car+rsu"], ["phone-active"])
    assert got == [
        ("los", "car+rsu", "phone-active"),
        ("rfsas+los", "car", "phone-active"),
        ("rfsas+los", "car+rsu", "phone-active"),
    ]
    with pytest.raises(ConfigError, match="unknown device 'phone-x'"):
        configs(["rfsas"], ["car"], ["phone-x"])
    # a name given twice runs once
    assert configs(["los", "los"], ["car", "car"], []) == [("los", "car+rsu", "phone-active")]


@pytest.mark.parametrize(
    ("controllers", "deployments", "devices", "match"),
    [
        ([], ["car"], ["phone-active"], "controllers: none chosen"),
        (["los", "rfsas"], [], ["phone-active"], "deployments: none chosen, and rfsas needs"),
        (["rfsas+los"], ["car"], [], "devices: none chosen, and rfsas\\+los needs"),
    ],
)
def test_a_selection_of_no_configuration_is_an_error_not_an_empty_sweep(
    controllers: list[str], deployments: list[str], devices: list[str], match: str
) -> None:
    with pytest.raises(ConfigError, match=match):
        configs(controllers, deployments, devices)


@pytest.mark.slow
def test_one_and_two_workers_give_the_same_results() -> None:
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    pytest.importorskip("distributed")
    cells = [Cell("CPNCO", 40.0, 0.5), Cell("TN-KERB", 30.0, 0.5)]
    conf = configs(["los", "rfsas+los"], ["car+rsu"], ["phone-active"])
    specs = specs_for(cells, conf, [0, 1])
    seen: list[int] = []
    one = run_sweep(specs, workers=1)
    two = run_sweep(specs, workers=2, on_result=lambda i, r: seen.append(i))
    assert sorted(seen) == list(range(len(specs)))
    assert [r.cell for r in two] == [s.cell.key for s in specs]
    for a, b in zip(one, two, strict=True):
        da, db = a.as_dict(), b.as_dict()
        for k in ("wall_s", "cpu_s"):
            da.pop(k), db.pop(k)
        assert da == db
    # and the same as running them here without Dask
    here = run_sweep(specs[:2], workers=0)
    times = {"wall_s": 0, "cpu_s": 0}
    assert [r.as_dict() | times for r in here] == [r.as_dict() | times for r in one[:2]]


def test_ctrl_c_during_a_run_here_ends_the_sweep_once_that_run_is_done(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import signal

    import rfsas_hw.ncap.sweep as sweep

    calls: list[str] = []

    def run(spec: object) -> str:
        calls.append("start")
        if len(calls) == 3:  # the second run: Ctrl-C in its middle (a kernel compiling)
            signal.raise_signal(signal.SIGINT)
        calls.append("end")
        return f"result {len(calls) // 2}"

    monkeypatch.setattr(sweep, "run_one", run)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    got: list[tuple[int, object]] = []
    specs = specs_for([Cell("CPNA", 20.0, 0.5)], configs(["los"], [], []), [0, 1, 2])
    try:
        with pytest.raises(KeyboardInterrupt):
            run_sweep(specs, workers=0, on_result=lambda i, r: got.append((i, r)))
    finally:
        signal.signal(signal.SIGINT, before)
    assert calls == ["start", "end", "start", "end"]  # the second run was not cut
    assert got == [(0, "result 1")]  # and the third never started
