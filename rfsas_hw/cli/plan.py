"""``rfsas plan``: time to first intercept of a scan plan, by simulation."""

from __future__ import annotations

import json
import math

import click
from rich.console import Console
from rich.table import Table

from rfsas_hw.cli.options import json_option
from rfsas_hw.errors import ConfigError
from rfsas_hw.twin.intercept import plan_report, receiver_plans


def _channels(text: str) -> tuple[int, ...]:
    """``1,6,11`` or ``1-13`` or a mix."""
    out: list[int] = []
    try:
        for part in text.split(","):
            part = part.strip()
            if "-" in part:
                lo, hi = part.split("-", 1)
                out.extend(range(int(lo), int(hi) + 1))
            elif part:
                out.append(int(part))
    except ValueError as err:
        raise ConfigError(f"--channels: cannot read {text!r}: use e.g. 1,6,11 or 1-13") from err
    if not out:
        raise ConfigError("--channels: no channel given")
    return tuple(out)


def _s(value: float) -> str:
    return (
        "never" if math.isinf(value) else f"{value * 1e3:.0f} ms" if value < 1 else f"{value:.2f} s"
    )


@click.command()
@click.option("--channels", default="1-13", show_default=True, help="Channels: 1,6,11 or 1-13.")
@click.option(
    "--dwell",
    "dwell_ms",
    type=click.FloatRange(min=0, min_open=True),
    default=100.0,
    show_default=True,
    help="Time on each channel, ms.",
)
@click.option(
    "--switch",
    "switch_ms",
    type=click.FloatRange(min=0.0),
    default=5.0,
    show_default=True,
    help="Dead time when the radio retunes, ms.",
)
@click.option(
    "--receivers",
    type=click.IntRange(1, 64),
    default=1,
    show_default=True,
    help="Receivers sharing the channel list.",
)
@click.option(
    "--emitter",
    type=click.Choice(["beacon", "probe", "ble"]),
    default="beacon",
    show_default=True,
    help="What is being looked for.",
)
@click.option(
    "--trials",
    type=click.IntRange(1, 10_000_000),
    default=2000,
    show_default=True,
    help="Simulated starts.",
)
@click.option(
    "--horizon",
    "horizon_s",
    type=click.FloatRange(min=0, min_open=True),
    default=30.0,
    show_default=True,
    help="Give up after this long, s.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@json_option("Print one JSON object.")
def plan(
    channels: str,
    dwell_ms: float,
    switch_ms: float,
    receivers: int,
    emitter: str,
    trials: int,
    horizon_s: float,
    seed: int,
    as_json: bool,
) -> None:
    """Mean and 90th-percentile time to first intercept of a scan plan, and its revisit time."""
    chans = _channels(channels)
    if emitter == "ble" and channels == "1-13":
        chans = (37, 38, 39)
    if trials < 1 or horizon_s <= 0:
        raise ConfigError("--trials must be at least 1 and --horizon positive")
    plans = receiver_plans(chans, dwell_ms / 1e3, receivers, switch_ms / 1e3)
    # one vectorised simulation: a status line, not a bar (it has no steps to count)
    with Console(stderr=True).status(f"simulating {trials:,} starts over {horizon_s:g} s…"):
        rep = plan_report(plans, emitter, trials=trials, horizon_s=horizon_s, seed=seed)  # type: ignore[arg-type]
    if as_json:
        click.echo(
            json.dumps(
                {
                    "channels": list(chans),
                    "dwell_ms": dwell_ms,
                    "receivers": receivers,
                    "emitter": emitter,
                    "mean_s": rep.mean_s,
                    "p90_s": rep.p90_s if math.isfinite(rep.p90_s) else None,
                    "median_s": rep.median_s if math.isfinite(rep.median_s) else None,
                    "intercepted": rep.intercepted,
                    "revisit_s": rep.revisit_s,
                    "mean_gap_s": rep.mean_gap_s,
                    "trials": rep.trials,
                }
            )
        )
        return
    table = Table(
        title=f"{emitter} on {len(chans)} channel(s), {receivers} receiver(s), "
        f"{dwell_ms:g} ms dwell"
    )
    table.add_column("quantity")
    table.add_column("value", justify="right")
    table.add_row("mean time to first intercept", _s(rep.mean_s))
    table.add_row("90th percentile", _s(rep.p90_s))
    table.add_row("median", _s(rep.median_s))
    table.add_row("heard within horizon", f"{rep.intercepted:.1%} of {rep.trials}")
    table.add_row("channel revisit time", _s(rep.revisit_s))
    for k, p in enumerate(plans):
        table.add_row(f"  receiver {k} channels", ",".join(str(c) for c in p.channels))
    if rep.mean_gap_s is not None:
        table.add_row("mean gap between coincidences T1·T2/(τ1+τ2)", _s(rep.mean_gap_s))
    Console().print(table)
