"""Independent tasks on Dask distributed: a local cluster by default, or a given scheduler.

The one runner of every sweep over seeds or cells (``rfsas ncap``, ``rfsas
sumo run --seeds``, ``rfsas sim train --seeds``). :func:`completed` hands
every item to Dask (one task each) and yields ``(index, result)`` as each
finishes; :func:`in_order` puts such pairs back in the order of the items;
:func:`run_tasks` collects them into a list in that order. The tasks must be
seeded and share no state, so the results do not depend on the number of
workers or on the order they finished in.

The local cluster runs worker processes with one thread each (libsumo runs
one simulation per process; PPO trains with one torch thread), listens on
the loopback interface only, on free ports, and is closed when the tasks are
done or one fails. ``workers=0`` without a scheduler runs the tasks in this
process, one after the other: no Dask needed, and the task function may then
be a closure (with Dask it must be picklable: a module-level function and
picklable items). With a scheduler, the workers are whatever is connected to
it; files that tasks write land on the workers' machines.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Callable, Generator, Iterable, Iterator, Sequence
from typing import Any, TypeVar

from rfsas_hw.errors import ConfigError
from rfsas_hw.optional import require

T = TypeVar("T")
R = TypeVar("R")

DEFAULT_WORKERS = 2
"""Worker processes of the local cluster when a command is not told (this machine class has
two cores)."""

__all__ = ["DEFAULT_WORKERS", "completed", "default_workers", "in_order", "run_tasks"]


def default_workers(tasks: int, *, here: bool = False) -> int:
    """The workers a command uses when not told: :data:`DEFAULT_WORKERS` for several tasks,
    0 (this process) for one task or when the tasks must run ``here`` (a GUI, a live
    connection, a per-step progress bar): a cluster's start-up would only cost time."""
    return 0 if here or tasks <= 1 else DEFAULT_WORKERS


def completed(
    fn: Callable[[T], R],
    items: Sequence[T],
    *,
    workers: int = DEFAULT_WORKERS,
    scheduler: str | None = None,
    name: str = "task",
) -> Generator[tuple[int, R]]:
    """``(index, fn(items[index]))`` for every item, in the order they finish.

    Args:
        fn: the task (module-level and picklable unless run here).
        items: its arguments, one task each.
        workers: worker processes of the local cluster (0: run here, without Dask).
        scheduler: address of a running Dask scheduler (then ``workers`` is not used).
        name: the tasks' name in Dask's dashboard.

    Raises:
        MissingDependencyError: Dask distributed is needed and not installed.
        ConfigError: ``scheduler`` is malformed or does not answer (after Dask's connect
            timeout, 30 s by default).
        ValueError: ``workers`` is negative.
        whatever ``fn`` raises (the first failing task's error; the others are cancelled).
    """
    if workers < 0:
        raise ValueError(f"workers must be >= 0, got {workers}")
    return _completed(fn, items, workers, scheduler, name)


def _completed(
    fn: Callable[[T], R], items: Sequence[T], workers: int, scheduler: str | None, name: str
) -> Generator[tuple[int, R]]:
    if scheduler is None and workers == 0:
        for i, item in enumerate(items):
            yield i, fn(item)
        return
    if not items:
        return
    distributed: Any = require("distributed")
    if not logging.getLogger().isEnabledFor(logging.INFO):
        # Dask sets its own loggers to INFO when imported: its start-up and shut-down
        # chatter would reach the terminal unless the application asked for INFO
        logging.getLogger("distributed").setLevel(logging.WARNING)
    cluster = None
    if scheduler is None:
        # loopback only, on free ports: nothing outside this machine can talk to the
        # scheduler, and a second cluster on the machine does not collide with it
        cluster = distributed.LocalCluster(
            n_workers=min(workers, len(items)),
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            scheduler_port=0,
            dashboard_address="127.0.0.1:0",
            # the workers' own logs stay quiet: a task's error reaches the caller through
            # its future, a lost worker as the scheduler's KilledWorker; what the workers
            # would print is the shut-down race of a heartbeat with the closing scheduler
            # (a traceback after every result was in)
            silence_logs=logging.CRITICAL,
        )
    try:
        with _client(distributed, cluster, scheduler) as client:
            # a fresh token per call: a scheduler shared with earlier sweeps never hands
            # back a result it still holds under the same key
            token = uuid.uuid4().hex[:12]
            keys = [f"{name}-{token}-{i}" for i in range(len(items))]
            futures = client.map(fn, list(items), key=keys, pure=False)
            index = {f.key: i for i, f in enumerate(futures)}
            try:
                for fut in distributed.as_completed(futures):
                    yield index[fut.key], fut.result()
            finally:
                client.cancel(futures)
    finally:
        if cluster is not None:
            cluster.close()


def _client(distributed: Any, cluster: Any, scheduler: str | None) -> Any:
    """A client of the local ``cluster``, or of the running ``scheduler``.

    Raises:
        ConfigError: the scheduler's address is malformed or nothing answers there.
    """
    if cluster is not None:
        return distributed.Client(cluster)
    try:
        return distributed.Client(scheduler)
    except (OSError, ValueError) as err:  # TimeoutError is an OSError
        raise ConfigError(f"Dask scheduler {scheduler!r}: cannot connect: {err}") from err


def in_order(pairs: Iterable[tuple[int, R]]) -> Iterator[tuple[int, R]]:
    """The ``(index, result)`` pairs of :func:`completed` in index order, each as soon as
    every earlier one has come (the later ones wait in memory until then)."""
    waiting: dict[int, R] = {}
    nxt = 0
    for i, r in pairs:
        waiting[i] = r
        while nxt in waiting:
            yield nxt, waiting.pop(nxt)
            nxt += 1


def run_tasks(
    fn: Callable[[T], R],
    items: Sequence[T],
    *,
    workers: int = DEFAULT_WORKERS,
    scheduler: str | None = None,
    name: str = "task",
    on_result: Callable[[int, R], None] | None = None,
) -> list[R]:
    """``fn`` of every item, in the order of ``items`` (see :func:`completed`).

    Args:
        on_result: called with each item's index and result as it finishes.

    Raises:
        as :func:`completed`.
    """
    results: dict[int, R] = {}
    pairs = completed(fn, items, workers=workers, scheduler=scheduler, name=name)
    try:
        for i, r in pairs:
            results[i] = r
            if on_result is not None:
                on_result(i, r)
    finally:
        pairs.close()
    return [results[i] for i in range(len(items))]
