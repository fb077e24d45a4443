"""The log records of a district run's processes: a child's warning reaches the main
process's handler (the run log's, in a run), not the console; MAC-shaped text never
leaves the child; the main process's own records land in the run log."""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
import queue
import sys
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from childhelp import answer_after_the_main_process_left, stop_when_told, warn_and_answer

from rfsas_hw.city.childlog import ChildLogging, LogRelay, child_main, install, redact_macs

MAC = "02:1a:2b:3c:4d:5e"


class Kept(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def _run_child(relay: LogRelay, name: str) -> None:
    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe()
    proc = ctx.Process(
        target=child_main, args=(warn_and_answer, MAC, child, relay.child()), name=name
    )
    proc.start()
    child.close()
    try:
        assert parent.poll(60), "the child did not answer"
        assert parent.recv() == "done"
    finally:
        proc.join(30)
        if proc.is_alive():
            proc.terminate()
            proc.join(5)
        parent.close()
    assert proc.exitcode == 0


def test_a_childs_warning_reaches_the_handler_not_stderr(capfd: pytest.CaptureFixture[str]) -> None:
    kept = Kept()
    relay = LogRelay(mp.get_context("spawn"), kept)
    try:
        _run_child(relay, "twin-1")
    finally:
        relay.close()  # hands over what is queued
    (record,) = kept.records  # the INFO record is below the main process's WARNING
    assert relay.level == logging.WARNING
    assert record.levelno == logging.WARNING and record.processName == "twin-1"
    assert record.getMessage() == "unit rsu-1 heard phone <mac>"
    err = capfd.readouterr().err
    assert "heard phone" not in err and MAC not in err


def test_by_default_a_childs_records_go_to_this_processs_loggers(
    caplog: pytest.LogCaptureFixture, capfd: pytest.CaptureFixture[str]
) -> None:
    relay = LogRelay(mp.get_context("spawn"))
    try:
        _run_child(relay, "be-1")
    finally:
        relay.close()
    got = [r for r in caplog.records if r.name == "rfsas_hw.city.testchild"]
    assert [(r.processName, r.getMessage()) for r in got] == [
        ("be-1", "unit rsu-1 heard phone <mac>")
    ]
    assert MAC not in capfd.readouterr().err


def test_a_full_queue_drops_records_and_then_says_how_many() -> None:
    q: queue.Queue[logging.LogRecord] = queue.Queue(maxsize=2)
    root = logging.getLogger()
    saved = (list(root.handlers), root.level)
    try:
        install(ChildLogging(q, logging.WARNING))  # this process stands for a child
        log = logging.getLogger("rfsas_hw.city.testchild")
        for i in range(5):
            log.warning("record %d", i)
        got = [q.get_nowait().getMessage() for _ in range(2)]
        log.warning("after")
        got += [q.get_nowait().getMessage() for _ in range(2)]
    finally:
        for handler in list(root.handlers):
            root.removeHandler(handler)
        for handler in saved[0]:
            root.addHandler(handler)
        root.setLevel(saved[1])
    assert got == [
        "record 0",
        "record 1",
        "3 log records dropped (the queue to the main process was full)",
        "after",
    ]
    assert q.empty()


@pytest.mark.parametrize(
    ("text", "redacted"),
    [
        ("phone 02:1A:2b:3c:4d:5e left", "phone <mac> left"),
        ("02-1a-2b-3c-4d-5e", "<mac>"),
        ("021a2b3c4d5e", "<mac>"),
        # emitter ids (16 hex digits), mixed separators and short numbers stay
        ("emitter 0123456789abcdef", "emitter 0123456789abcdef"),
        ("02:1a-2b:3c:4d:5e", "02:1a-2b:3c:4d:5e"),
        ("seq 123456", "seq 123456"),
    ],
)
def test_mac_shaped_text_is_redacted(text: str, redacted: str) -> None:
    assert redact_macs(text) == redacted


def test_the_main_processs_records_land_in_the_run_log(grid_net: Path, tmp_path: Path) -> None:
    pytest.importorskip("libsumo", reason="needs the city extra: pip install 'rfsas-hw[city]'")
    from rfsas_hw.city.demand import DemandConfig
    from rfsas_hw.city.run import CityRunConfig, run_city

    cfg = CityRunConfig(
        net=grid_net,
        duration_s=2.0,
        seed=1,
        demand=DemandConfig(vehicles=5, pedestrians=5, bicycles=0, end_s=1.0),
    )
    said: list[Any] = []

    def progress(p: Any) -> None:
        if not said:
            logging.getLogger("rfsas_hw.city.test").warning("phone %s near a unit", MAC)
            said.append(p)

    res = run_city(cfg, tmp_path / "out", "off", png=False, on_progress=progress)
    records = [json.loads(ln) for ln in res.files["log"].read_text().splitlines()]
    logged = [r for r in records if r["record"] == "log"]
    assert [(r["process"], r["level"], r["logger"], r["message"]) for r in logged] == [
        ("main", "WARNING", "rfsas_hw.city.test", "phone <mac> near a unit")
    ]
    assert res.runtime.log_records == {"WARNING": 1}
    assert MAC not in res.files["log"].read_text()
    # the handler is gone once the run is over
    assert not any(type(h).__name__ == "_LogRecords" for h in logging.getLogger().handlers)


def test_a_child_answering_a_closed_pipe_ends_quietly(capfd: pytest.CaptureFixture[str]) -> None:
    """The main process gave up on a child (a failed start, a stop deadline passed) and
    closed its end: the child's answer finds the pipe broken. It ends with exit code 0
    and no traceback on the console (the main process counted the missing answer)."""
    ctx = mp.get_context("spawn")
    relay = LogRelay(ctx)
    parent, child = ctx.Pipe()
    release, release_end = ctx.Pipe()
    proc = ctx.Process(
        target=child_main,
        args=(answer_after_the_main_process_left, release_end, child, relay.child()),
        name="vehicles",
    )
    try:
        proc.start()
        child.close()
        release_end.close()
        parent.close()  # the main process stops listening
        release.send("go")
        proc.join(60)
        assert not proc.is_alive(), "the child did not end"
        assert proc.exitcode == 0
    finally:
        if proc.is_alive():
            proc.terminate()
            proc.join(5)
        release.close()
        relay.close()
    err = capfd.readouterr().err
    assert "BrokenPipeError" not in err and "Traceback" not in err


def test_ctrl_c_at_the_terminal_leaves_a_child_to_be_stopped_by_the_main_process(
    capfd: pytest.CaptureFixture[str],
) -> None:
    """Ctrl-C reaches every process of the group; a district process must not die of it
    (with a traceback each) but end when the main process stops it over its pipe."""
    import os
    import signal

    ctx = mp.get_context("spawn")
    relay = LogRelay(ctx)
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=child_main, args=(stop_when_told, None, child, relay.child()))
    try:
        proc.start()
        child.close()
        assert parent.poll(60) and parent.recv() == "ready"
        os.kill(proc.pid, signal.SIGINT)  # as the terminal does, while it waits on its pipe
        parent.send("stop")
        assert parent.poll(60), "the child did not answer"
        assert parent.recv() == "stopped"
        proc.join(60)
        assert proc.exitcode == 0
    finally:
        if proc.is_alive():
            proc.terminate()
            proc.join(5)
        parent.close()
        relay.close()
    assert "KeyboardInterrupt" not in capfd.readouterr().err
