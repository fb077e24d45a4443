"""Sweeps of the matrix on the project's runner (:mod:`rfsas_hw.parallel`: Dask distributed,
a local cluster by default, or a given scheduler).

:func:`run_sweep` hands every :class:`~rfsas_hw.ncap.runner.RunSpec` to the
runner (one task each) and gives the results back in the order of the specs,
whatever order they finished in. Every run is seeded and uses no shared
state, so the results do not depend on the number of workers. ``workers=0``
without a scheduler runs the specs in this process, one after the other (no
Dask needed: for small runs and tests).

:func:`specs_for` builds the spec list of a sweep: cells × configurations ×
seeds; a configuration is ``none``, ``los``, or ``rfsas``/``rfsas+los`` with a
deployment and a device model (``rfsas+los/car+rsu/phone-active``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from itertools import product
from typing import cast

from rfsas_hw.errors import ConfigError
from rfsas_hw.ncap.rfsas import DEPLOYMENTS, DEVICES, Deployment
from rfsas_hw.ncap.runner import CONTROLLERS, Controller, RunResult, RunSpec, run_one
from rfsas_hw.ncap.scenarios import Cell
from rfsas_hw.parallel import DEFAULT_WORKERS, run_tasks
from rfsas_hw.runner import signals_held

__all__ = ["configs", "run_sweep", "run_whole", "specs_for"]


def configs(
    controllers: Iterable[str], deployments: Iterable[str], devices: Iterable[str]
) -> list[tuple[Controller, Deployment, str]]:
    """Every configuration of the chosen controllers, deployments and devices (``none`` and
    ``los`` once each: they use no RF-SAS).

    A name given twice counts once.

    Raises:
        ConfigError: an unknown controller, deployment or device (names the known ones);
            no controller, or an RF-SAS controller with no deployment or no device.
    """
    ctls, deps, devs = (list(dict.fromkeys(x)) for x in (controllers, deployments, devices))
    for name, given, known in (
        ("controller", ctls, CONTROLLERS),
        ("deployment", deps, DEPLOYMENTS),
        ("device", devs, DEVICES),
    ):
        for g in given:
            if g not in known:
                raise ConfigError(f"unknown {name} {g!r} (known: {', '.join(known)})")
    if not ctls:
        raise ConfigError(f"controllers: none chosen (known: {', '.join(CONTROLLERS)})")
    rf = [c for c in ctls if c not in ("none", "los")]
    for name, given, known in (("deployments", deps, DEPLOYMENTS), ("devices", devs, DEVICES)):
        if rf and not given:
            raise ConfigError(
                f"{name}: none chosen, and {', '.join(rf)} needs one (known: {', '.join(known)})"
            )
    out: list[tuple[Controller, Deployment, str]] = []
    for c in ctls:
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
    workers: int = DEFAULT_WORKERS,
    scheduler: str | None = None,
    on_result: Callable[[int, RunResult], None] | None = None,
) -> list[RunResult]:
    """Run every spec on the project's runner (:func:`rfsas_hw.parallel.run_tasks`); the
    results in the order of ``specs``.

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
    return run_tasks(
        run_whole, specs, workers=workers, scheduler=scheduler, name="ncap", on_result=on_result
    )


def run_whole(spec: RunSpec) -> RunResult:
    """:func:`~rfsas_hw.ncap.runner.run_one`, with Ctrl-C and SIGTERM held until the run
    is done (:func:`~rfsas_hw.runner.signals_held`; in the main thread only, so on a Dask
    worker it holds nothing). A run takes a fraction of a second, but the first in a fresh
    install compiles the numeric kernels for seconds, and an interrupt inside numba's
    compiler comes out as its own RuntimeError instead of a KeyboardInterrupt.

    Raises:
        as :func:`~rfsas_hw.ncap.runner.run_one`; KeyboardInterrupt once the run is done
            when Ctrl-C (or SIGTERM, as the CLI's :class:`~rfsas_hw.runner.Terminated`)
            came during it.
    """
    with signals_held():
        return run_one(spec)
