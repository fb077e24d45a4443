"""The start handshake of a district's processes: a warm-up that compiles kernels is
judged by the CPU it uses, not by the wall clock a loaded machine stretches.

The processes are played by pipes this test writes to itself; the waiting side's
``idle`` (called every poll interval) moves the play on, so every wall time below is a
lower bound that load only lengthens."""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Iterator
from multiprocessing.connection import Connection

import pytest

from rfsas_hw.city.handshake import POLL_S, answer_failure, wait_ready
from rfsas_hw.errors import SimulationError


@pytest.fixture
def pipes() -> Iterator[list[tuple[Connection, Connection]]]:
    made: list[tuple[Connection, Connection]] = []
    yield made
    for ours, theirs in made:
        ours.close()
        theirs.close()


def _pipe(pipes: list[tuple[Connection, Connection]]) -> tuple[Connection, Connection]:
    ours, theirs = mp.Pipe()
    pipes.append((ours, theirs))
    return ours, theirs


class _Compiling:
    """The CPU time of a process that is compiling: up 0.01 s at every look."""

    def __init__(self) -> None:
        self.used = 0.0

    def __call__(self, pid: int) -> float:
        self.used += 0.01
        return self.used


def test_a_warm_up_longer_than_the_start_time_is_waited_for(
    pipes: list[tuple[Connection, Connection]],
) -> None:
    ours, theirs = _pipe(pipes)
    theirs.send(("warming",))
    polls = 0

    def idle() -> None:  # the compile ends after 12 poll intervals, > start_s
        nonlocal polls
        polls += 1
        if polls == 12:
            theirs.send(("ready",))

    wait_ready({"be-1": (ours, 1)}, idle, start_s=12 * POLL_S / 2, cpu_s=_Compiling())
    assert polls == 12


def test_the_warm_up_does_not_eat_the_next_process_start(
    pipes: list[tuple[Connection, Connection]],
) -> None:
    first, first_end = _pipe(pipes)
    second, second_end = _pipe(pipes)
    first_end.send(("warming",))
    polls = 0
    start_s = 2.0
    warm_polls = int(start_s / POLL_S) + 5  # the first one's warm-up: > start_s

    def idle() -> None:
        nonlocal polls
        polls += 1
        if polls == warm_polls:
            first_end.send(("ready",))
        elif polls == warm_polls + 1:  # the second answers just after: in its start time
            second_end.send(("ready",))

    wait_ready(
        {"be-1": (first, 1), "twin-1": (second, 2)}, idle, start_s=start_s, cpu_s=_Compiling()
    )
    assert polls == warm_polls + 1


def test_a_warm_up_past_its_cpu_budget_fails_naming_the_process(
    pipes: list[tuple[Connection, Connection]],
) -> None:
    ours, theirs = _pipe(pipes)
    theirs.send(("warming",))
    cpu = _Compiling()
    with pytest.raises(SimulationError, match=r"be-2: its warm-up .* more than 0\.05 s of CPU"):
        wait_ready({"be-2": (ours, 1)}, start_s=60.0, warm_cpu_s=0.05, cpu_s=cpu)
    assert cpu.used > 0.05


def test_a_warm_up_that_uses_no_cpu_is_stuck(pipes: list[tuple[Connection, Connection]]) -> None:
    ours, theirs = _pipe(pipes)
    theirs.send(("warming",))
    with pytest.raises(SimulationError, match=r"twin-3: its warm-up used no CPU for 0\.3 s"):
        wait_ready({"twin-3": (ours, 1)}, start_s=0.3, cpu_s=lambda pid: 7.0)


def test_silence_exit_and_errors_before_ready(pipes: list[tuple[Connection, Connection]]) -> None:
    silent, _ = _pipe(pipes)
    with pytest.raises(SimulationError, match=r"be-1 did not start within 0\.3 s"):
        wait_ready({"be-1": (silent, 1)}, start_s=0.3)
    gone, gone_end = _pipe(pipes)
    gone_end.send(("warming",))
    gone_end.close()
    with pytest.raises(SimulationError, match="be-1 exited before it was ready"):
        wait_ready({"be-1": (gone, 1)}, cpu_s=_Compiling())
    failed, failed_end = _pipe(pipes)
    failed_end.send(("error", "backend be-1: KeyError: 'x'"))
    with pytest.raises(SimulationError, match="backend be-1: KeyError"):
        wait_ready({"be-1": (failed, 1)})
    odd, odd_end = _pipe(pipes)
    odd_end.send(("step", 1.0))
    with pytest.raises(SimulationError, match=r"twin-1: \('step', 1.0\)"):
        wait_ready({"twin-1": (odd, 1)})


class _BrokenOnClose:
    def __init__(self) -> None:
        self.closed = 0

    def close(self) -> None:
        self.closed += 1
        raise OSError("broker gone")


def test_a_failure_is_answered_with_the_first_error_after_closing_what_was_built(
    pipes: list[tuple[Connection, Connection]],
) -> None:
    ours, theirs = _pipe(pipes)
    built = _BrokenOnClose()
    try:
        raise KeyError("veh-7")
    except KeyError as err:
        answer_failure(theirs, "backend be-1", err, built)
    assert built.closed == 1
    with pytest.raises(SimulationError) as failed:
        wait_ready({"backend be-1": (ours, 0)}, cpu_s=lambda pid: 0.0)
    assert str(failed.value) == "backend be-1: KeyError: 'veh-7'"
