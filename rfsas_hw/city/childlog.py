"""Log records of a district run's processes, handed to the main process.

The twin workers, the backends and the vehicles' gateway are processes of their own
(forked from a server, :mod:`rfsas_hw.city.live`): without a logging configuration
of their own, Python's last-resort handler writes each of their warnings to the
console, under the main process's progress display. Each of them instead runs
:func:`child_main`, which gives its root logger one handler: a bounded queue to the
main process, at the main process's level. In the main process a :class:`LogRelay`
takes the records from the queue on a thread of its own and hands them to one
handler — the run log's (:func:`rfsas_hw.city.run.run_city` writes them there, with
the main process's own records) or, by default, this process's loggers, as if they
had been logged here.

Raw MAC addresses exist only inside the twin workers: before a record leaves its
process, anything in its text shaped like a MAC (six octets in hex, with ``:``, ``-``
or nothing between them) is replaced by ``<mac>``. A child that logs faster than the
main process takes its records drops the excess (the queue holds
:data:`QUEUE_RECORDS`) and says how many once the queue has room again.
"""

from __future__ import annotations

import logging
import queue
import re
import signal
from collections.abc import Callable
from dataclasses import dataclass
from logging.handlers import QueueHandler, QueueListener
from multiprocessing.connection import Connection
from typing import Any

QUEUE_RECORDS = 10_000
"""Records in flight from the children to the main process, at most."""

MAC_TEXT = re.compile(
    r"(?i)(?<![0-9a-f])[0-9a-f]{2}([:-]?)[0-9a-f]{2}(?:\1[0-9a-f]{2}){4}(?![0-9a-f])"
)
"""Six octets in hex, separated by ``:``, ``-`` or nothing (one separator throughout)."""

__all__ = ["MAC_TEXT", "QUEUE_RECORDS", "ChildLogging", "LogRelay", "child_main", "redact_macs"]


def redact_macs(text: str) -> str:
    """``text`` with everything shaped like a MAC address replaced by ``<mac>``."""
    return MAC_TEXT.sub("<mac>", text)


@dataclass(frozen=True)
class ChildLogging:
    """What a child process needs to log to the main process (picklable as a process
    argument)."""

    queue: Any
    """The relay's multiprocessing queue."""
    level: int
    """The child's root level: the main process's effective level at the start."""


class _ToParent(QueueHandler):
    """A queue handler that redacts MAC-shaped text and drops (and later reports) what
    does not fit in the bounded queue, instead of blocking or raising."""

    def __init__(self, q: Any) -> None:
        super().__init__(q)
        self.dropped = 0

    def prepare(self, record: logging.LogRecord) -> logging.LogRecord:
        record = super().prepare(record)  # formats the message and any traceback into msg
        record.msg = redact_macs(str(record.msg))
        return record

    def enqueue(self, record: logging.LogRecord) -> None:
        try:
            if self.dropped:
                note = logging.makeLogRecord(
                    {
                        "name": __name__,
                        "levelno": logging.WARNING,
                        "levelname": "WARNING",
                        "msg": f"{self.dropped} log records dropped (the queue to the main "
                        "process was full)",
                        "processName": record.processName,
                    }
                )
                self.queue.put_nowait(note)
                self.dropped = 0
            self.queue.put_nowait(record)
        except queue.Full:
            self.dropped += 1


def install(cfg: ChildLogging) -> None:
    """Make this (child) process's root logger send every record at ``cfg.level`` or
    above to the main process, and nothing to the console."""
    root = logging.getLogger()
    for handler in list(root.handlers):
        root.removeHandler(handler)
    root.addHandler(_ToParent(cfg.queue))
    root.setLevel(cfg.level)


def child_main(
    target: Callable[[Any, Connection], None], work: Any, conn: Connection, cfg: ChildLogging
) -> None:
    """The body of a district process: Ctrl-C (SIGINT) ignored, its logging to the main
    process (:func:`install`), then ``target(work, conn)``.

    A pipe to the main process found closed (``BrokenPipeError``, ``ConnectionResetError``)
    ends the process quietly: the main process closed its end because it stopped the
    run (at a failed start, or past its stop deadline) and counts the answer it did not
    get (``... ended without its counters``); there is nobody left to report to.
    """
    # Ctrl-C at a terminal reaches the whole process group: the main process stops the
    # run and then its processes over their pipes, which a KeyboardInterrupt here would
    # cut short (a traceback from every process, and their counters lost)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    install(cfg)
    try:
        target(work, conn)
    except (BrokenPipeError, ConnectionResetError) as err:
        logging.getLogger(__name__).debug("the main process closed the pipe: %s", err)


class _AsIfHere(logging.Handler):
    """Hands a record to this process's logger of its name, as if it had been logged
    here (its level, filters and handlers apply)."""

    def emit(self, record: logging.LogRecord) -> None:
        logger = logging.getLogger(record.name)
        if logger.isEnabledFor(record.levelno):
            logger.handle(record)


class _Listener(QueueListener):
    def __init__(self, q: Any, handler: logging.Handler) -> None:
        super().__init__(q, handler)
        self._bounded = q

    def enqueue_sentinel(self) -> None:
        # the queue is bounded: wait for room rather than fail to stop
        self._bounded.put(getattr(self, "_sentinel", None), timeout=10.0)


class LogRelay:
    """The main process's end: a bounded queue the children log to, and a thread that
    hands their records to ``handler`` (default: this process's loggers).

    Args:
        ctx: the multiprocessing context the children are started from.
        handler: where the children's records go.
        maxsize: records in flight, at most.
    """

    def __init__(
        self, ctx: Any, handler: logging.Handler | None = None, maxsize: int = QUEUE_RECORDS
    ) -> None:
        self.queue = ctx.Queue(maxsize)
        self.level = logging.getLogger().getEffectiveLevel()
        self._listener = _Listener(self.queue, handler or _AsIfHere())
        self._listener.start()
        self._closed = False

    def child(self) -> ChildLogging:
        """What a child process is given to log here (see :func:`child_main`)."""
        return ChildLogging(self.queue, self.level)

    def close(self) -> None:
        """Hand over what is queued, stop the thread and close the queue (call once the
        children have ended). Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._listener.stop()
        self.queue.close()
        self.queue.join_thread()
