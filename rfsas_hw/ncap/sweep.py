"""Sweeps of the matrix on Dask distributed: a local cluster by default, or a given scheduler.

:func:`run_sweep` hands every :class:`~rfsas_hw.ncap.runner.RunSpec` to Dask
(one task each; workers are processes with one thread, because libsumo runs
one simulation per process) and gives the results back in the order of the
specs, whatever order they finished in. Every run is seeded and uses no
shared state, so the results do not depend on the number of workers.
The local cluster listens on the loopback interface only, on free ports.
``workers=0`` without a scheduler runs the specs in this process, one after
the other (no Dask needed: for small runs and tests).

:func:`specs_for` builds the spec list of a sweep: cells × configurations ×
seeds; a configuration is ``none``, ``los``, or ``rfsas``/``rfsas+los`` with a
deployment and a device model (``rfsas+los/car+rsu/phone-active``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from itertools import product
from typing import Any, cast

from rfsas_hw.errors import ConfigError
from rfsas_hw.ncap.rfsas import DEPLOYMENTS, DEVICES, Deployment
from rfsas_hw.ncap.runner import CONTROLLERS, Controller, RunResult, RunSpec, run_one
from rfsas_hw.ncap.scenarios import Cell
from rfsas_hw.optional import require

__all__ = ["configs", "run_sweep", "specs_for"]


def configs(
    controllers: Iterable[str], deployments: Iterable[str], devices: Iterable[str]
) -> list[tuple[Controller, Deployment, str]]:
    """Every configuration of the chosen controllers, deployments and devices (``none`` and
    ``los`` once each: they use no RF-SAS).

    Raises:
        ConfigError: an unknown controller, deployment or device (names the known ones).
    """
    deps, devs = list(deployments), list(devices)
    for name, given, known in (
        ("controller", controllers, CONTROLLERS),
        ("deployment", deps, DEPLOYMENTS),
        ("device", devs, DEVICES),
    ):
        for g in given:
            if g not in known:
                raise ConfigError(f"unknown {name} {g!r} (known: {', '.join(known)})")
    out: list[tuple[Controller, Deployment, str]] = []
    for c in controllers:
        ctl = cast(Controller, c)
        if ctl in ("none", "los"):
            out.append((ctl, "car+rsu", DEVICES[0]))
        else:
            out.extend((ctl, cast(Deployment, d), v) for d, v in product(deps, devs))
    return out


def specs_for(
    cells: Sequence[Cell],
    configurations: Sequence[tuple[Controller, Deployment, str]],
    seeds: Sequence[int],
) -> list[RunSpec]:
    """Every run of a sweep, cell by cell, configuration by configuration, seed by seed."""
    return [
        RunSpec(cell, ctl, dep, dev, seed)
        for cell in cells
        for ctl, dep, dev in configurations
        for seed in seeds
    ]


def run_sweep(
    specs: Sequence[RunSpec],
    *,
    workers: int = 2,
    scheduler: str | None = None,
    on_result: Callable[[int, RunResult], None] | None = None,
) -> list[RunResult]:
    """Run every spec; the results in the order of ``specs``.

    Args:
        specs: the runs.
        workers: worker processes of the local cluster (0: run here, without Dask).
        scheduler: address of a running Dask scheduler (then ``workers`` is not used).
        on_result: called with each spec's index and result as it finishes.

    Raises:
        MissingDependencyError: Dask distributed is needed and not installed.
        ValueError: ``workers`` is negative.
        as :func:`~rfsas_hw.ncap.runner.run_one` (the first failing run's error).
    """
    if workers < 0:
        raise ValueError("workers must be >= 0")
    results: list[RunResult | None] = [None] * len(specs)
    if scheduler is None and workers == 0:
        for i, spec in enumerate(specs):
            done = results[i] = run_one(spec)
            if on_result is not None:
                on_result(i, done)
        return cast(list[RunResult], results)
    distributed: Any = require("distributed")
    cluster = None
    if scheduler is None:
        # loopback only, on free ports: nothing outside this machine can talk to the
        # scheduler, and a second sweep (or another cluster) does not collide with it
        cluster = distributed.LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            scheduler_port=0,
            dashboard_address="127.0.0.1:0",
            silence_logs=logging.ERROR,
        )
    try:
        with distributed.Client(cluster if cluster is not None else scheduler) as client:
            keys = [f"ncap-{i}-{s.cell.key}-{s.config}-{s.seed}" for i, s in enumerate(specs)]
            futures = client.map(run_one, list(specs), key=keys, pure=False)
            index = {f.key: i for i, f in enumerate(futures)}
            for fut in distributed.as_completed(futures):
                i = index[fut.key]
                done = results[i] = fut.result()
                if on_result is not None:
                    on_result(i, done)
    finally:
        if cluster is not None:
            cluster.close()
    return cast(list[RunResult], results)
