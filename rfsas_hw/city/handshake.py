"""The start handshake of a district run's processes: started, warmed up, ready.

A twin worker, a backend or the vehicles' gateway answers on its pipe, once built
(connected to the broker, keys loaded), ``("warming",)`` if it has compiled kernels
to load, then ``("ready",)``. The two phases are judged differently:

- the start (up to ``("warming",)``, or to ``("ready",)`` for a process without a
  warm-up) is I/O and imports: it has :data:`START_TIMEOUT_S` of wall time;
- the warm-up loads numba's compiled kernels, or compiles them the first time in a
  source tree: tens of seconds of CPU, which on a loaded machine can stretch to many
  minutes of wall time. It is judged by the process's own CPU time instead: it fails
  once it used more than :data:`WARM_CPU_S`, or used none for :data:`START_TIMEOUT_S`
  (stuck, not slow).

A warm-up does not eat into the start time of the processes waited for after it.

A process that fails, then or later, answers ``("error", message)``
(:func:`answer_failure`) and ends; the main process ends the run with the message.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Mapping
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Protocol

from rfsas_hw.errors import SimulationError

log = logging.getLogger(__name__)

START_TIMEOUT_S = 60.0
"""How long a process may take to be built and answer, wall seconds."""
WARM_CPU_S = 600.0
"""How much CPU a process's warm-up (compiling its kernels) may use, seconds."""
POLL_S = 0.1
"""How often the waiting side looks at the pipe and calls its ``idle``, seconds."""

__all__ = [
    "POLL_S",
    "START_TIMEOUT_S",
    "WARM_CPU_S",
    "answer_failure",
    "proc_cpu_s",
    "wait_ready",
]


class _Closes(Protocol):
    def close(self) -> object: ...


def answer_failure(conn: Connection, name: str, err: Exception, built: _Closes | None) -> None:
    """Answer a process's failure on its pipe: ``("error", "NAME: Type: text")``.

    Call it while handling ``err``. ``built`` (what the process had built, or None)
    is closed first; a failure to close it is only logged at debug level, since the
    first error is the one to report. Never raises on its own account (the send
    may raise as any send on ``conn``).
    """
    log.debug("%s failed", name, exc_info=True)
    text = f"{name}: {type(err).__name__}: {err}"
    if built is not None:
        try:
            built.close()
        except Exception:  # already failing: the first error is the one to report
            log.debug("closing %s failed too", name, exc_info=True)
    conn.send(("error", text))


def proc_cpu_s(pid: int) -> float:
    """CPU time of a process from /proc (0 where it cannot be read), seconds."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return 0.0


def wait_ready(
    conns: Mapping[str, tuple[Connection, int]],
    idle: Callable[[], object] = lambda: None,
    *,
    start_s: float = START_TIMEOUT_S,
    warm_cpu_s: float = WARM_CPU_S,
    cpu_s: Callable[[int], float] = proc_cpu_s,
) -> None:
    """Wait until every process has answered ``("ready",)`` (see the module docstring).

    Args:
        conns: per process name, our end of its pipe and its process id.
        idle: called every :data:`POLL_S` while waiting (the nonce authority's tick).
        start_s: wall time a process has to be built, seconds.
        warm_cpu_s: CPU time a process's warm-up may use, seconds.
        cpu_s: CPU time of a process id, seconds (:func:`proc_cpu_s`).

    Raises:
        SimulationError: a process did not start in time, its warm-up used more than
            ``warm_cpu_s`` or stalled, it exited, or it answered an error.
    """
    deadline = time.monotonic() + start_s
    for name, (conn, pid) in conns.items():
        warm_from: float | None = None
        """The process's CPU time when its warm-up began, seconds."""
        while True:
            progress_cpu, progress_at = -1.0, time.monotonic()
            while not conn.poll(POLL_S):
                idle()
                now = time.monotonic()
                if warm_from is None:
                    if now > deadline:
                        raise SimulationError(f"{name} did not start within {start_s:g} s")
                    continue
                used = cpu_s(pid)
                if used - warm_from > warm_cpu_s:
                    raise SimulationError(
                        f"{name}: its warm-up (compiling kernels) used more than "
                        f"{warm_cpu_s:g} s of CPU"
                    )
                if used > progress_cpu:
                    progress_cpu, progress_at = used, now
                elif now - progress_at > start_s:
                    raise SimulationError(
                        f"{name}: its warm-up used no CPU for {start_s:g} s (stuck)"
                    )
            try:
                msg = conn.recv()
            except EOFError:
                raise SimulationError(f"{name} exited before it was ready") from None
            if msg[0] == "warming" and warm_from is None:
                warm_from = cpu_s(pid)
                continue
            if msg[0] != "ready":
                raise SimulationError(str(msg[1]) if msg[0] == "error" else f"{name}: {msg!r}")
            break
        if warm_from is not None:  # the others' start goes on from here
            deadline = max(deadline, time.monotonic() + start_s)
