"""``rfsas link watch``: verify what arrives on a port and show each sender's link health."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path

import click
from rich.console import Console
from rich.live import Live
from rich.table import Table

from rfsas_hw.cli.linkopts import join_urls, split_urls
from rfsas_hw.cli.options import duration_option, json_option, keys_option
from rfsas_hw.link import Receiver, ReceiverConfig
from rfsas_hw.link.fallback import FallbackReceiver
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.latency import LatencyConfig, LinkState

STATE_STYLE = {LinkState.OK: "green", LinkState.LATE: "bold yellow", LinkState.SILENT: "bold red"}


def _ms(value: float) -> str:
    return "–" if math.isnan(value) else f"{value:.1f}"


def render(rx: Receiver, now_ns: int) -> Table:
    """Per-sender state, ages and losses, with the receiver's counters as the caption."""
    table = Table(title=f"link health (budget {rx.config.latency.budget_s * 1e3:.0f} ms)")
    for col in ("sender", "state", "messages", "lost", "late %", "p50 ms", "p99 ms", "silent s"):
        table.add_column(col, justify="left" if col in ("sender", "state") else "right")
    for s in rx.latency.snapshot(now_ns).values():
        table.add_row(
            s.sender_id,
            f"[{STATE_STYLE[s.state]}]{s.state.value}[/]",
            f"{s.messages:,}",
            f"{s.lost:,}",
            "–" if math.isnan(s.late_fraction) else f"{100 * s.late_fraction:.0f}",
            _ms(s.p50_ms),
            _ms(s.p99_ms),
            f"{s.silent_for_s:.1f}",
        )
    stats = rx.stats
    rejected = ", ".join(f"{k} {v:,}" for k, v in sorted(stats.rejected.items())) or "none"
    table.caption = (
        f"datagrams {stats.datagrams:,}  verified {stats.verified:,}  rejected: {rejected}"
        f"  {'ALARM' if rx.latency.alarm else 'ok'}"
    )
    return table


@click.group()
def link() -> None:
    """The signed bearing link: watch what arrives."""


@link.command("watch")
@click.option(
    "--listen",
    "url",
    required=True,
    multiple=True,
    callback=join_urls,
    metavar="URL",
    help="Where safety messages arrive: udp://HOST:PORT (unicast or multicast) or a "
    "broker (mqtt://, mqtts://…); repeat to take several at once.",
)
@keys_option("Key directory whose trust/ holds the sensors' cards.")
@click.option(
    "--expect",
    multiple=True,
    metavar="SENSOR_ID",
    help="A sensor that should be heard (silent until it is); repeatable.",
)
@click.option(
    "--budget-ms",
    type=click.FloatRange(min=0, min_open=True),
    default=100.0,
    show_default=True,
    help="Latency budget, milliseconds.",
)
@click.option(
    "--no-epoch-check",
    is_flag=True,
    help="Accept messages of any nonce epoch (recorded captures sent by replay).",
)
@duration_option("Stop after this many seconds (default: Ctrl-C).")
@json_option("No live table; one JSON status line at the end.")
@click.option(
    "--fallback",
    metavar="URL",
    help="Also listen on this out-of-band path: each path is watched on its own and a "
    "message that came both ways is counted once (the table shows the primary).",
)
def watch(
    url: str,
    keys_dir: Path,
    expect: tuple[str, ...],
    budget_ms: float,
    no_epoch_check: bool,
    duration: float | None,
    as_json: bool,
    fallback: str | None,
) -> None:
    """Verify safety messages and show, per sender, its state (ok / late / silent),
    message ages against the budget, and losses; rejected datagrams by reason."""
    config = ReceiverConfig(
        check_epoch=not no_epoch_check, latency=LatencyConfig(budget_s=budget_ms / 1e3)
    )
    trust = KeyStore.open(keys_dir).trust
    rx = Receiver.listen(split_urls(url), trust, config=config)
    rx.latency.expect(expect, time.time_ns())
    both: FallbackReceiver | None = None
    if fallback is not None:
        try:
            both = FallbackReceiver(rx, Receiver.listen(split_urls(fallback), trust, config=config))
        except BaseException:
            rx.close()
            raise
    stop = None if duration is None else time.monotonic() + duration

    def loop(show: Callable[[], None]) -> None:
        while stop is None or time.monotonic() < stop:
            wait = 0.2 if stop is None else max(0.0, min(0.2, stop - time.monotonic()))
            if both is not None:
                both.receive(timeout=wait)
            else:
                rx.receive(timeout=wait)
            show()

    def table() -> Table:
        shown = render(rx, time.time_ns())
        if both is not None:
            shown.caption = (
                f"{shown.caption}  fallback: verified {both.secondary.stats.verified:,}, "
                f"duplicates {both.duplicates:,}"
            )
        return shown

    try:
        if as_json:
            loop(lambda: None)
        else:
            with Live(table(), console=Console(), auto_refresh=False) as live:
                loop(lambda: live.update(table(), refresh=True))
    except KeyboardInterrupt:
        pass
    finally:
        if both is not None:
            both.close()
        else:
            rx.close()
    if as_json:
        snap = rx.latency.snapshot(time.time_ns())
        status = {
            "stats": rx.stats.as_dict(),
            "alarm": rx.latency.alarm,
            "senders": {
                k: {
                    "state": v.state.value,
                    "messages": v.messages,
                    "lost": v.lost,
                    "p99_ms": None if math.isnan(v.p99_ms) else round(v.p99_ms, 3),
                }
                for k, v in snap.items()
            },
        }
        if both is not None:
            status["fallback"] = {
                "stats": both.secondary.stats.as_dict(),
                "delivered": dict(both.delivered),
                "duplicates": both.duplicates,
                "primary_alarm": both.primary_alarm,
            }
        click.echo(json.dumps(status, sort_keys=True))
