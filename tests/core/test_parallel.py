"""The one runner of every sweep: results in the order of the items, errors not swallowed."""

from __future__ import annotations

import math

import pytest

from rfsas_hw.errors import ConfigError
from rfsas_hw.parallel import completed, default_workers, in_order, run_tasks


def test_in_order_releases_each_result_once_every_earlier_one_came() -> None:
    got = list(in_order([(2, "c"), (0, "a"), (3, "d"), (1, "b")]))
    assert got == [(0, "a"), (1, "b"), (2, "c"), (3, "d")]


def test_here_runs_closures_in_order_and_reports_each() -> None:
    seen: list[tuple[int, int]] = []
    offset = 10
    out = run_tasks(
        lambda x: x + offset, [3, 1, 2], workers=0, on_result=lambda i, r: seen.append((i, r))
    )
    assert out == [13, 11, 12] and seen == [(0, 13), (1, 11), (2, 12)]


def test_bad_worker_counts_are_refused_at_once() -> None:
    with pytest.raises(ValueError, match="workers must be >= 0, got -1"):
        completed(abs, [1], workers=-1)


def test_default_workers() -> None:
    assert default_workers(1) == 0 and default_workers(5) == 2
    assert default_workers(5, here=True) == 0


@pytest.mark.slow
def test_dask_gives_results_in_item_order_and_the_first_error() -> None:
    pytest.importorskip("distributed", reason="needs the ncap extra: pip install 'rfsas-hw[ncap]'")
    items = [float(x) for x in range(12, 0, -1)]
    assert run_tasks(math.sqrt, items, workers=2, name="t") == [math.sqrt(x) for x in items]
    with pytest.raises(ValueError, match="math domain error"):
        run_tasks(math.sqrt, [4.0, -1.0, 9.0], workers=1)
    assert run_tasks(math.sqrt, [], workers=2) == []


@pytest.mark.parametrize(
    ("address", "why"),
    [("no-port-here", "missing port number"), ("tcp://127.0.0.1:1", "Timed out")],
    ids=["malformed", "nobody listens"],
)
def test_a_scheduler_that_cannot_be_reached_is_named_in_one_error(address: str, why: str) -> None:
    pytest.importorskip("distributed", reason="needs the ncap extra: pip install 'rfsas-hw[ncap]'")
    import dask

    # port 1 refuses at once; Dask retries until its connect timeout, kept short here
    with (
        dask.config.set({"distributed.comm.timeouts.connect": "1s"}),
        pytest.raises(ConfigError, match=f"Dask scheduler '{address}': cannot connect: .*{why}"),
    ):
        run_tasks(abs, [1, 2], scheduler=address)
