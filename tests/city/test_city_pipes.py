"""A district process that ended during the run: the main process's next send to it
fails with the error the process reported (or that it ended), not a bare
``BrokenPipeError`` from deep in the step."""

from __future__ import annotations

import multiprocessing as mp

import pytest

from rfsas_hw.city.live import send_or_end
from rfsas_hw.errors import SimulationError


def test_a_send_to_a_process_that_failed_carries_its_error() -> None:
    ours, theirs = mp.Pipe()
    try:
        theirs.send(("error", "backend be-1: KeyError: 'veh-7'"))
        theirs.close()  # it ended
        with pytest.raises(SimulationError, match="backend be-1: KeyError: 'veh-7'"):
            for _ in range(1000):  # the first sends may still fit the socket's buffer
                send_or_end("be-1", ours, ("states", b"x" * 4096))
    finally:
        ours.close()


def test_a_send_to_a_process_that_ended_silently_names_it() -> None:
    ours, theirs = mp.Pipe()
    try:
        theirs.close()
        with pytest.raises(SimulationError, match="twin-2 ended during the run"):
            for _ in range(1000):
                send_or_end("twin-2", ours, ("step", b"x" * 4096))
    finally:
        ours.close()


def test_a_send_to_a_live_process_arrives() -> None:
    ours, theirs = mp.Pipe()
    try:
        send_or_end("vehicles' gateway", ours, ("veh-1", "veh-2"))
        assert theirs.poll(30)
        assert theirs.recv() == ("veh-1", "veh-2")
    finally:
        ours.close()
        theirs.close()
