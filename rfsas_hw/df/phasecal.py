"""Phase calibration of an antenna pair: the offset (and chain delay) the interferometer removes.

Fitted from frames of one transmitter at known angles — a turntable log, or
a transmitter at a surveyed position (one known angle) — by comparing the
measured phase difference with the geometric one:

    φ_cal = circular mean over frames of (Δφ_measured − 2π·(D/λ)·sin θ_true)

per channel (cables and filters make it frequency dependent). The chain
delay is the mean slope of the residual across subcarriers. The residual's
circular spread beyond the frames' own noise, plus the offset's standard
error (degrees of Δφ), is stored and added to every bearing's σ.

Stored in the calibration YAML beside the amplitude tables under ``phase:``::

    phase:
      fov_deg: [-60.0, 60.0]
      pairs:
        - a: 0
          b: 1
          baseline_m: 0.0612
          offsets:
            - {channel: 6, offset_deg: 41.3, delay_ns: 0.12, residual_deg: 3.9, samples: 1200}
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.df.interferometer import SUBCARRIER_SPACING_HZ, geometric_phase_rad
from rfsas_hw.errors import CalibrationError
from rfsas_hw.records import CsiBlock

MIN_SAMPLES = 10
"""Fewest frames a channel's offset is fitted from."""


@dataclass(frozen=True, slots=True)
class PhaseOffset:
    """The calibrated phase of one pair on one channel."""

    channel: int | None
    """IEEE channel; None for every channel."""
    offset_deg: float
    """Δφ measured minus Δφ geometric, degrees, (−180, 180]."""
    delay_ns: float = 0.0
    """Extra delay of antenna b's chain over a's, ns (a phase slope across subcarriers)."""
    residual_deg: float = 0.0
    """Circular spread of the per-frame residual after calibration, degrees of Δφ."""
    samples: int = 0
    """Frames it was fitted from."""


@dataclass(frozen=True, slots=True)
class PhasePair:
    """One interferometer baseline and its calibrated offsets."""

    a: int
    """Reference antenna (anticlockwise end of the baseline)."""
    b: int
    """Other antenna (clockwise end)."""
    baseline_m: float
    """Antenna spacing D, metres."""
    offsets: tuple[PhaseOffset, ...]
    """One entry per channel, or one with ``channel: None`` for all."""

    def offset_for(self, channel: int | None) -> PhaseOffset | None:
        """The channel's offset, else the all-channel one, else None."""
        fallback = None
        for o in self.offsets:
            if o.channel is not None and o.channel == channel:
                return o
            if o.channel is None:
                fallback = o
        return fallback


@dataclass(frozen=True, slots=True)
class PhaseCalibration:
    """Phase calibration of every interferometer pair of a sensor."""

    pairs: tuple[PhasePair, ...]
    """Baselines; the first is the one bearings are computed on."""
    fov_deg: tuple[float, float] = (-60.0, 60.0)
    """Field of view of the interferometer, degrees from boresight."""


def fit_phase_offset(
    csi: CsiBlock,
    true_deg: npt.ArrayLike,
    freq_mhz: npt.ArrayLike,
    baseline_m: float,
    *,
    a: int = 0,
    b: int = 1,
    channel: int | None = None,
) -> PhaseOffset:
    """Fit one pair's offset, chain delay and residual from frames at known angles.

    Args:
        csi: the frames' CSI (one transmitter).
        true_deg: angle of the transmitter from boresight per frame, degrees clockwise.
        freq_mhz: centre frequency per frame (or one), MHz.
        baseline_m: antenna spacing, metres.
        a, b: the pair.
        channel: channel the offset is for (None: all).

    Raises:
        CalibrationError: fewer than :data:`MIN_SAMPLES` frames with both antennas,
            or no frequency.
    """
    n = len(csi)
    where = "all channels" if channel is None else f"channel {channel}"
    freq = np.broadcast_to(np.asarray(freq_mhz, np.float64), (n,))
    if n and not np.all(freq > 0):
        raise CalibrationError(f"{where}: frames without a frequency; give it (freq=MHz)")
    theta = np.broadcast_to(np.asarray(true_deg, np.float64), (n,))
    # the common sampling-time offset cancels in this product: no remove_sto
    z = csi.h[:, b] * np.conj(csi.h[:, a])  # (n, n_tx, n_sc)
    sub_mhz = csi.subcarrier.astype(np.float64) * SUBCARRIER_SPACING_HZ / 1e6
    geo = geometric_phase_rad(theta[:, None], freq[:, None] + sub_mhz[None, :], baseline_m)
    z = z * np.exp(-1j * geo)[:, None, :]
    ok = np.isfinite(z) & (z != 0)
    z = np.where(ok, z, 0)
    used = ok.any(axis=(1, 2))
    if int(used.sum()) < MIN_SAMPLES:
        raise CalibrationError(
            f"{where}: {int(used.sum())} frames with both antennas {a} and {b}; "
            f"need at least {MIN_SAMPLES}"
        )
    z = z[used]
    sub = csi.subcarrier.astype(np.int64)
    steps = np.diff(sub)
    delay_ns = 0.0
    if len(steps):
        step = int(np.bincount(np.abs(steps)).argmax()) or 1
        pick = np.flatnonzero(steps == step)
        slope = float(np.angle(np.sum(z[..., pick + 1] * np.conj(z[..., pick])))) / step
        delay_ns = slope / (2 * math.pi * SUBCARRIER_SPACING_HZ) * 1e9
        z = z * np.exp(-1j * slope * sub)[None, None, :]
    per_frame = z.sum(axis=(1, 2))
    unit = per_frame / np.abs(per_frame)
    mean = complex(unit.mean())
    offset = math.atan2(mean.imag, mean.real)
    r = min(abs(mean), 1.0)
    spread2 = -2.0 * math.log(max(r, 1e-300))
    # the frames' own noise (each frame's subcarrier spread) is charged to every
    # bearing by its SNR already: keep only the excess (model error, multipath)
    # and the uncertainty of the fitted offset itself
    dev = np.angle(z * np.conj(unit)[:, None, None])
    w = np.abs(z)
    terms = np.maximum((w > 0).sum(axis=(1, 2)), 1)
    noise2 = float(np.mean((w * dev**2).sum(axis=(1, 2)) / w.sum(axis=(1, 2)) / terms))
    samples = int(used.sum())
    residual2 = max(spread2 - noise2, 0.0) + spread2 / samples
    return PhaseOffset(
        channel, math.degrees(offset), delay_ns, math.degrees(math.sqrt(residual2)), samples
    )


def fit_phase_pair(
    csi: CsiBlock,
    true_deg: npt.ArrayLike,
    freq_mhz: npt.ArrayLike,
    channel: npt.ArrayLike,
    baseline_m: float,
    *,
    a: int = 0,
    b: int = 1,
    per_channel: bool = True,
) -> PhasePair:
    """A pair's calibration: one offset per channel found (or one for all).

    Raises:
        CalibrationError: as :func:`fit_phase_offset`, naming the channel.
    """
    ch = np.asarray(channel, np.int64)
    n = len(csi)
    freq = np.broadcast_to(np.asarray(freq_mhz, np.float64), (n,))
    theta = np.broadcast_to(np.asarray(true_deg, np.float64), (n,))
    channels = sorted({int(c) for c in ch if int(c) != 0})
    groups: list[tuple[int | None, npt.NDArray[np.bool_]]]
    if per_channel and channels:
        groups = [(c, ch == c) for c in channels]
    else:
        groups = [(None, np.ones(n, bool))]
    offsets = tuple(
        fit_phase_offset(csi.select(mask), theta[mask], freq[mask], baseline_m, a=a, b=b, channel=c)
        for c, mask in groups
    )
    return PhasePair(a, b, baseline_m, offsets)


def _number(value: Any, where: str) -> float:
    if isinstance(value, int | float) and not isinstance(value, bool):
        try:
            number = float(value)
        except OverflowError:
            number = math.inf
        if math.isfinite(number):
            return number
    shown = f"{value!r}"
    raise CalibrationError(
        f"{where}: must be a finite number, got {shown[:40]}{'…' if len(shown) > 40 else ''}"
    )


def _keys(data: Mapping[str, Any], allowed: set[str], required: set[str], where: str) -> None:
    unknown = set(data) - allowed
    if unknown:
        raise CalibrationError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
    missing = required - set(data)
    if missing:
        raise CalibrationError(f"{where}: missing key(s) {', '.join(sorted(missing))}")


def phase_from_mapping(data: Any, where: str) -> PhaseCalibration:
    """Validate the ``phase:`` section of a calibration file.

    Raises:
        CalibrationError: wrong shape, unknown or missing key, bad value (key named).
    """
    if not isinstance(data, Mapping):
        raise CalibrationError(f"{where}: expected a mapping")
    _keys(data, {"fov_deg", "pairs"}, {"pairs"}, where)
    fov = data.get("fov_deg", [-60.0, 60.0])
    if not (isinstance(fov, list | tuple) and len(fov) == 2):
        raise CalibrationError(f"{where}.fov_deg: expected [lower, upper]")
    lo, hi = (_number(v, f"{where}.fov_deg") for v in fov)
    if not -90.0 < lo < hi < 90.0:
        raise CalibrationError(f"{where}.fov_deg: [{lo:g}, {hi:g}] must lie inside (−90, 90)")
    raw_pairs = data["pairs"]
    if not isinstance(raw_pairs, list) or not raw_pairs:
        raise CalibrationError(f"{where}.pairs: expected a non-empty list")
    pairs = []
    for i, p in enumerate(raw_pairs):
        pw = f"{where}.pairs[{i}]"
        if not isinstance(p, Mapping):
            raise CalibrationError(f"{pw}: expected a mapping")
        _keys(p, {"a", "b", "baseline_m", "offsets"}, {"a", "b", "baseline_m", "offsets"}, pw)
        a, b = p["a"], p["b"]
        if not (type(a) is int and type(b) is int and 0 <= a < 8 and 0 <= b < 8 and a != b):
            raise CalibrationError(f"{pw}: a and b must be two different antennas 0–7")
        baseline = _number(p["baseline_m"], f"{pw}.baseline_m")
        if baseline <= 0:
            raise CalibrationError(f"{pw}.baseline_m: must be positive, got {baseline:g}")
        if not isinstance(p["offsets"], list) or not p["offsets"]:
            raise CalibrationError(f"{pw}.offsets: expected a non-empty list")
        offsets = []
        seen: set[int | None] = set()
        for k, o in enumerate(p["offsets"]):
            ow = f"{pw}.offsets[{k}]"
            if not isinstance(o, Mapping):
                raise CalibrationError(f"{ow}: expected a mapping")
            _keys(
                o,
                {"channel", "offset_deg", "delay_ns", "residual_deg", "samples"},
                {"offset_deg"},
                ow,
            )
            ch = o.get("channel")
            if ch is not None and not (type(ch) is int and 0 < ch < 1000):
                raise CalibrationError(f"{ow}.channel: expected a channel number or null")
            if ch in seen:
                raise CalibrationError(f"{ow}.channel: second offset for channel {ch}")
            seen.add(ch)
            residual = _number(o.get("residual_deg", 0.0), f"{ow}.residual_deg")
            if residual < 0:
                raise CalibrationError(f"{ow}.residual_deg: must be ≥ 0")
            samples = o.get("samples", 0)
            if type(samples) is not int or samples < 0:
                raise CalibrationError(f"{ow}.samples: expected a count ≥ 0")
            offsets.append(
                PhaseOffset(
                    ch,
                    _number(o["offset_deg"], f"{ow}.offset_deg"),
                    _number(o.get("delay_ns", 0.0), f"{ow}.delay_ns"),
                    residual,
                    samples,
                )
            )
        pairs.append(PhasePair(a, b, baseline, tuple(offsets)))
    return PhaseCalibration(tuple(pairs), (lo, hi))


def phase_to_mapping(cal: PhaseCalibration) -> dict[str, Any]:
    """The ``phase:`` section of a calibration file (plain types)."""
    return {
        "fov_deg": [float(cal.fov_deg[0]), float(cal.fov_deg[1])],
        "pairs": [
            {
                "a": p.a,
                "b": p.b,
                "baseline_m": float(f"{p.baseline_m:.9g}"),
                "offsets": [
                    {
                        "channel": o.channel,
                        "offset_deg": round(o.offset_deg, 4),
                        "delay_ns": round(o.delay_ns, 5),
                        "residual_deg": round(o.residual_deg, 4),
                        "samples": o.samples,
                    }
                    for o in p.offsets
                ],
            }
            for p in cal.pairs
        ],
    }
