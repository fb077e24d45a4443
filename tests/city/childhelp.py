"""Bodies of test child processes (importable by name in a spawned child: the test puts
this folder on ``sys.path``, which a spawned process inherits)."""

from __future__ import annotations

import logging
from multiprocessing.connection import Connection

log = logging.getLogger("rfsas_hw.city.testchild")


def warn_and_answer(phone: str, conn: Connection) -> None:
    """Log a warning naming ``phone`` (a MAC), an INFO record, then answer ``done``."""
    log.warning("unit rsu-1 heard phone %s", phone)
    log.info("a record below the main process's level")
    conn.send("done")
    conn.close()


def answer_nice(_work: object, conn: Connection) -> None:
    """Answer this process's nice value."""
    import os

    conn.send(os.nice(0))
    conn.close()


def answer_after_the_main_process_left(release: Connection, conn: Connection) -> None:
    """Wait until told (the main process has closed its end of ``conn`` by then), then
    answer on ``conn`` as a district process answers at its end, and report the failure
    as it does."""
    release.recv()
    try:
        conn.send(("end", "counters"))
    except Exception as err:
        conn.send(("error", f"{type(err).__name__}: {err}"))


def stop_when_told(_work: object, conn: Connection) -> None:
    """Say ``ready``, wait for ``stop``, then answer ``stopped`` (a district process's end)."""
    conn.send("ready")
    assert conn.recv() == "stop"
    conn.send("stopped")
    conn.close()
