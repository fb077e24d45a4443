"""Scan plans and the time to first intercept (method.md §8).

A receiver hears a frame when it sits on the frame's channel for the whole
frame. With several receivers the channel list is split between them
(receiver ``k`` takes channels ``k, k+N, k+2N, …``) and the first intercept
is the earliest over all of them.

For periodic receiver windows (period ``T1``, width ``τ1``) and periodic
emitter activity (period ``T2``, width ``τ2``) the mean gap between
coincidences is ``T1·T2/(τ1 + τ2)`` (Self & Smith, 1985): :func:`mean_gap_closed_form`,
checked against :func:`mean_gap_simulated`. The mean time to the *first*
intercept from a random start is a different number; it is computed here by
simulation over random phases of the emitter and the receivers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import ConfigError
from rfsas_hw.twin.scan import ScanPlan
from rfsas_hw.twin.scenario import TrafficSpec
from rfsas_hw.twin.traffic import transmissions

EmitterModel = Literal["beacon", "probe", "ble"]

AIRTIME_S: dict[str, float] = {"beacon": 2.0e-3, "probe": 0.8e-3, "ble": 0.376e-3}
"""Time on air of one frame: a ~250-byte beacon and a ~100-byte probe request at
1 Mb/s, a full 31-byte BLE advertising PDU at 1 Mb/s."""


def receiver_plans(
    channels: tuple[int, ...], dwell_s: float, n_receivers: int = 1, switch_s: float = 0.0
) -> list[ScanPlan]:
    """Split ``channels`` between ``n_receivers`` receivers, each hopping with ``dwell_s``.

    Raises:
        ConfigError: no channels, fewer channels than receivers, or bad times.
    """
    if n_receivers < 1:
        raise ConfigError(f"need at least one receiver, got {n_receivers}")
    if len(channels) < n_receivers:
        raise ConfigError(f"{n_receivers} receivers cannot share {len(channels)} channel(s)")
    try:
        return [
            ScanPlan(
                tuple(channels[k::n_receivers]),
                dwell_s,
                switch_s if len(channels[k::n_receivers]) > 1 else 0.0,
            )
            for k in range(n_receivers)
        ]
    except ValueError as err:
        raise ConfigError(f"scan plan: {err}") from err


def emitter_traffic(model: EmitterModel, channels: tuple[int, ...]) -> TrafficSpec:
    """The traffic model of an emitter kind for a plan over ``channels``.

    ``beacon``: an AP on one channel (drawn per trial), every 102.4 ms;
    ``probe``: a phone sweeping every channel of the plan in bursts every 2 s
    (±0.2 s), 2 frames per channel, 15 ms per channel; ``ble``: advertising
    every 100 ms plus 0–10 ms on channels 37/38/39.
    """
    if model == "beacon":
        return TrafficSpec(model="beacon", channels=channels[:1])
    if model == "probe":
        return TrafficSpec(model="probe-bursts", channels=channels)
    if model == "ble":
        return TrafficSpec(model="ble-adv")
    raise ConfigError(f"unknown emitter model {model!r}: use beacon, probe or ble")


def first_intercepts(
    plans: list[ScanPlan],
    model: EmitterModel,
    *,
    trials: int = 2000,
    horizon_s: float = 30.0,
    airtime_s: float | None = None,
    interval_s: float | None = None,
    seed: int = 0,
) -> npt.NDArray[np.float64]:
    """Time from a random start to the first frame heard, seconds, one value per trial.

    Each trial draws the emitter's phase (and, for a beacon, its channel
    among the plans' channels) and every receiver's plan offset at random.
    Trials without an intercept within ``horizon_s`` give ``inf``.
    """
    rng = np.random.default_rng(seed)
    all_channels = tuple(sorted({c for p in plans for c in p.channels}))
    air = AIRTIME_S[model] if airtime_s is None else airtime_s
    out = np.full(trials, np.inf)
    for k in range(trials):
        spec = emitter_traffic(model, all_channels)
        if model == "beacon":
            spec = TrafficSpec(model="beacon", channels=(int(rng.choice(all_channels)),))
        if interval_s is not None:
            spec = TrafficSpec(
                model=spec.model,
                channels=spec.channels,
                interval_s=interval_s,
                jitter_ms=spec.jitter_ms,
            )
        tx = transmissions(spec, horizon_s, rng)
        best = np.inf
        for plan in plans:
            offset = rng.uniform(0.0, plan.period_s)
            shifted = ScanPlan(plan.channels, plan.dwell_s, plan.switch_s, offset)
            start_ok = shifted.channel_at(tx.t_s) == tx.channel
            end_ok = shifted.channel_at(tx.t_s + air) == tx.channel
            # the radio must not leave the channel during the frame
            same_dwell = np.floor((tx.t_s - offset) / plan.dwell_s) == np.floor(
                (tx.t_s + air - offset) / plan.dwell_s
            )
            heard = start_ok & end_ok & (same_dwell | (len(plan.channels) == 1))
            if heard.any():
                best = min(best, float(tx.t_s[np.argmax(heard)] + air))
        out[k] = best
    return out


@dataclass(frozen=True)
class InterceptReport:
    """Statistics of the time to first intercept for one plan and emitter kind."""

    mean_s: float
    """Mean time to first intercept over intercepted trials, seconds."""
    p90_s: float
    """90th percentile over all trials (inf if more than 10 % were never heard), seconds."""
    median_s: float
    """Median over all trials, seconds."""
    intercepted: float
    """Fraction of trials with an intercept within the horizon."""
    revisit_s: float
    """Channel revisit time: the longest plan period among the receivers, seconds."""
    trials: int
    """Number of trials."""
    mean_gap_s: float | None
    """Closed-form mean gap between coincidences for a beacon, ``T1·T2/(τ1+τ2)``, seconds."""


def plan_report(
    plans: list[ScanPlan],
    model: EmitterModel,
    *,
    trials: int = 2000,
    horizon_s: float = 30.0,
    seed: int = 0,
) -> InterceptReport:
    """Simulate :func:`first_intercepts` and summarise."""
    t = first_intercepts(plans, model, trials=trials, horizon_s=horizon_s, seed=seed)
    hit = np.isfinite(t)
    gap = None
    if model == "beacon":
        p = plans[0]
        listen = p.dwell_s - p.switch_s if len(p.channels) > 1 else p.dwell_s
        gap = mean_gap_closed_form(p.period_s, listen, 0.1024, AIRTIME_S["beacon"])
    return InterceptReport(
        mean_s=float(np.mean(t[hit])) if hit.any() else float("inf"),
        p90_s=float(np.quantile(t, 0.9)),
        median_s=float(np.quantile(t, 0.5)),
        intercepted=float(np.mean(hit)),
        revisit_s=max(p.period_s for p in plans),
        trials=trials,
        mean_gap_s=gap,
    )


def mean_gap_closed_form(t1_s: float, tau1_s: float, t2_s: float, tau2_s: float) -> float:
    """Mean gap between coincidences of two periodic windows, ``T1·T2/(τ1 + τ2)``, seconds."""
    return t1_s * t2_s / (tau1_s + tau2_s)


def mean_gap_simulated(
    t1_s: float, tau1_s: float, t2_s: float, tau2_s: float, horizon_s: float, phase_s: float = 0.0
) -> float:
    """Mean gap between coincidences, counted over ``horizon_s``: horizon / number of overlaps.

    A coincidence is an emitter window ``[φ + k·T2, φ + k·T2 + τ2)`` that
    overlaps a receiver window ``[j·T1, j·T1 + τ1)``.
    """
    k = np.arange(int(horizon_s / t2_s))
    start = phase_s + k * t2_s
    # overlap iff the emitter window starts within (−τ2, τ1) of a receiver window start
    into = np.mod(start + tau2_s, t1_s)
    hits = int(np.count_nonzero(into < tau1_s + tau2_s))
    return horizon_s / hits if hits else float("inf")
