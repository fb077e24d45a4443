"""The RF activity prior: where and when emitters have been located, as decaying counts.

The backend's fixes say where phones were heard. Over days this becomes a map
of the site's activity: how many RF-detected road users pass through each
tile (``tile_m`` square, in the site's local frame), per hour of day once the
history spans ``hourly_after_days``. A vehicle's planner (or the learning
environment, :mod:`rfsas_hw.envs`) asks :meth:`ActivityPrior.density_ahead`
for the expected number of road users per hour in a corridor along its path.

What is kept (and persisted by :meth:`ActivityPrior.save`):

- per tile and hour of day, the decayed number of *visits*: an emitter
  entering a tile counts once; it counts again in the same tile only after
  ``revisit_s`` without a fix there;
- per hour of day, the decayed observed time (seconds in which fixes were
  arriving, gaps longer than ``max_gap_s`` excluded), so counts become rates;
- the times of the first and last record.

Everything decays with the half-life ``half_life_h`` so that a site's old
habits fade. No emitter id is ever stored in the prior or its file: the
de-duplication of visits keeps, in memory only, the last tile of each
emitter seen in the past ``revisit_s`` and forgets it after that.

Times are UTC nanoseconds; the hour of day is the UTC hour (a site far from
UTC sees its rush hours shifted, not mixed).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import ConfigError, DataFormatError
from rfsas_hw.records import Assessment, Fix

__all__ = ["FORMAT", "ActivityPrior", "PriorConfig", "PriorSink"]

FORMAT = "rfsas-activity-prior"
"""Value of the ``format`` key of a prior file."""
VERSION = 1
NS_PER_S = 1_000_000_000
HOURS = 24
_RENORMALISE_HALF_LIVES = 200.0
"""Counts are kept scaled to a reference time; past this many half-lives it is moved."""

Array = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class PriorConfig:
    """How the activity prior counts and forgets.

    Raises:
        ConfigError: a non-positive size, half-life or gap.
    """

    tile_m: float = 5.0
    """Side of a square tile of the site's local frame, metres."""
    half_life_h: float = 168.0
    """Half-life of every count, hours (one week)."""
    hourly_after_days: float = 7.0
    """Per-hour-of-day rates are used once the history spans this many days; before
    that all hours are pooled."""
    revisit_s: float = 30.0
    """An emitter counts again in the same tile only after this long without a fix there, s."""
    max_gap_s: float = 60.0
    """A gap between records longer than this is not counted as observed time, seconds."""

    def __post_init__(self) -> None:
        for name in ("tile_m", "half_life_h", "revisit_s", "max_gap_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"activity prior: {name} must be > 0, got {getattr(self, name)}")
        if self.hourly_after_days < 0:
            raise ConfigError("activity prior: hourly_after_days must be >= 0")


def _hour(t_ns: int) -> int:
    return (t_ns // (3600 * NS_PER_S)) % HOURS


class ActivityPrior:
    """Decaying visit counts per tile and hour of day (see the module docstring).

    Also a result sink of :class:`~rfsas_hw.backend.service.BackendService`
    (:meth:`on_results`): trustworthy fixes are counted as they are made.

    Args:
        config: tile size, half-life and counting rules.
    """

    def __init__(self, config: PriorConfig | None = None) -> None:
        self.config = config or PriorConfig()
        self._lambda_per_ns = math.log(2.0) / (self.config.half_life_h * 3600 * NS_PER_S)
        self._ref_ns: int | None = None
        """Counts and exposure are stored multiplied by exp(λ·(t_event − ref))."""
        self._counts: dict[tuple[int, int], Array] = {}
        self._exposure = np.zeros(HOURS)
        self.first_ns: int | None = None
        """Time of the first record, UTC ns (None: empty)."""
        self.last_ns: int | None = None
        """Time of the newest record, UTC ns."""
        self._recent: dict[str, dict[tuple[int, int], int]] = {}
        """emitter → {tile: last fix time}: in memory only, forgotten after ``revisit_s``."""

    # -- counting ------------------------------------------------------------------------

    def tile_of(self, x_m: float, y_m: float) -> tuple[int, int]:
        """Index (east, north) of the tile holding a point."""
        s = self.config.tile_m
        return math.floor(x_m / s), math.floor(y_m / s)

    def _weight(self, t_ns: int) -> float:
        if self._ref_ns is None:
            self._ref_ns = t_ns
        exponent = self._lambda_per_ns * (t_ns - self._ref_ns)
        if exponent > _RENORMALISE_HALF_LIVES * math.log(2.0):
            self._rebase(t_ns)
            exponent = 0.0
        return math.exp(exponent)

    def _rebase(self, t_ns: int) -> None:
        assert self._ref_ns is not None
        factor = math.exp(-self._lambda_per_ns * (t_ns - self._ref_ns))
        for counts in self._counts.values():
            counts *= factor
        self._exposure *= factor
        self._ref_ns = t_ns

    def _advance(self, t_ns: int) -> None:
        """Account observed time up to ``t_ns`` and forget stale emitters."""
        if self.first_ns is None:
            self.first_ns = t_ns
        if self.last_ns is not None and t_ns > self.last_ns:
            gap_s = (t_ns - self.last_ns) / NS_PER_S
            if gap_s <= self.config.max_gap_s:
                # split the gap over the hours it spans (rarely more than one)
                t = self.last_ns
                while t < t_ns:
                    end = min(t_ns, (t // (3600 * NS_PER_S) + 1) * 3600 * NS_PER_S)
                    self._exposure[_hour(t)] += (end - t) / NS_PER_S * self._weight(end)
                    t = end
            horizon = t_ns - int(self.config.revisit_s * NS_PER_S)
            recent = {}
            for e, tiles in self._recent.items():
                kept = {k: t for k, t in tiles.items() if t >= horizon}
                if kept:
                    recent[e] = kept
            self._recent = recent
        if self.last_ns is None or t_ns > self.last_ns:
            self.last_ns = t_ns

    def observe(self, t_ns: int) -> None:
        """Mark ``t_ns`` as a time the backend was running (for steps without fixes)."""
        self._advance(int(t_ns))

    def add_fix(self, t_ns: int, x_m: float, y_m: float, emitter: str) -> bool:
        """Count one located emitter; True when it started a new visit of a tile.

        ``emitter`` is only used to tell a new visit from the same road user's
        next fix; it is kept in memory for ``revisit_s`` and never stored.
        Non-finite positions are ignored.
        """
        t_ns = int(t_ns)
        if not (math.isfinite(x_m) and math.isfinite(y_m)):
            return False
        self._advance(t_ns)
        tile = self.tile_of(x_m, y_m)
        tiles = self._recent.setdefault(emitter, {})
        last = tiles.get(tile)
        tiles[tile] = max(t_ns, last or t_ns)
        if last is not None and t_ns - last <= self.config.revisit_s * NS_PER_S:
            return False
        counts = self._counts.get(tile)
        if counts is None:
            counts = self._counts[tile] = np.zeros(HOURS)
        counts[_hour(t_ns)] += self._weight(t_ns)
        return True

    def add_fixes(self, fixes: Iterable[Fix]) -> int:
        """Count trustworthy fixes (``ok``) in time order; the number of new visits."""
        n = 0
        for fix in sorted((f for f in fixes if f.ok), key=lambda f: f.t_ns):
            n += self.add_fix(fix.t_ns, fix.x_m, fix.y_m, fix.emitter)
        return n

    def on_results(self, fixes: Sequence[Fix], assessments: Sequence[Assessment]) -> None:
        """Result-sink hook: count the step's trustworthy fixes."""
        self.add_fixes(fixes)

    def close(self) -> None:
        """Result-sink hook: forget the in-memory emitter table."""
        self._recent.clear()

    @classmethod
    def from_run(
        cls, path: str | Path, config: PriorConfig | None = None
    ) -> tuple[ActivityPrior, int]:
        """Build a prior from a backend run log (``rfsas backend --out run.jsonl``).

        Every ``fix`` and ``assessment`` line's time counts as observed; the
        trustworthy fixes are counted. A line that is not JSON or lacks a field
        costs only itself. Returns the prior and the number of skipped lines.

        Raises:
            DataFormatError: the file cannot be read.
        """
        p = Path(path)
        prior = cls(config)
        skipped = 0
        try:
            fh = p.open("r", encoding="utf-8", errors="replace")
        except OSError as err:
            raise DataFormatError(f"{p}: cannot read the run log: {err.strerror or err}") from err
        with fh:
            for line in fh:
                if not line.strip():
                    continue
                try:
                    rec = json.loads(line)
                    kind = rec.get("record")
                    if kind not in ("fix", "assessment"):
                        continue
                    t_ns = int(rec["t_ns"])
                    if kind == "fix" and rec.get("ok"):
                        x, y = rec["x_m"], rec["y_m"]
                        if x is not None and y is not None:
                            prior.add_fix(t_ns, float(x), float(y), str(rec["emitter"]))
                            continue
                    prior.observe(t_ns)
                except (ValueError, TypeError, KeyError, AttributeError):
                    skipped += 1
        prior.close()
        return prior, skipped

    # -- queries -------------------------------------------------------------------------

    def _decay_to(self, t_ns: int | None) -> float:
        """Factor turning stored values into values decayed to ``t_ns`` (default: newest)."""
        if self._ref_ns is None:
            return 1.0
        t = self.last_ns if t_ns is None else int(t_ns)
        assert t is not None
        return math.exp(-self._lambda_per_ns * (t - self._ref_ns))

    @property
    def history_days(self) -> float:
        """Span of the history, days (0 when empty)."""
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return (self.last_ns - self.first_ns) / (86400 * NS_PER_S)

    @property
    def hourly(self) -> bool:
        """Whether queries use per-hour-of-day rates (the history is long enough)."""
        return (
            self.history_days >= self.config.hourly_after_days and self.config.hourly_after_days > 0
        )

    def visits(self, tile: tuple[int, int], t_ns: int | None = None) -> Array:
        """Decayed visits of one tile per hour of day (24 values) at ``t_ns`` (default: newest)."""
        counts = self._counts.get(tile)
        if counts is None:
            return np.zeros(HOURS)
        return counts * self._decay_to(t_ns)

    def observed_s(self, t_ns: int | None = None) -> Array:
        """Decayed observed time per hour of day, seconds (24 values)."""
        return self._exposure * self._decay_to(t_ns)

    def tiles(self) -> list[tuple[int, int]]:
        """Tiles with at least one visit."""
        return sorted(self._counts)

    def _rates(self, hour: int | None) -> tuple[dict[tuple[int, int], float], float]:
        """Visits per hour of every tile, for the hour of day ``hour`` or pooled."""
        if self.hourly and hour is not None:
            idx: Any = hour % HOURS
        else:
            idx = slice(None)
        exposure_h = float(np.sum(self._exposure[idx])) / 3600.0
        if exposure_h <= 0:
            return {}, 0.0
        return {k: float(np.sum(v[idx])) / exposure_h for k, v in self._counts.items()}, exposure_h

    def rate_per_h(self, x_m: float, y_m: float, hour: int | None = None) -> float:
        """Visits per hour of the tile holding a point (pooled over hours unless
        :attr:`hourly` and ``hour`` is given); 0 without observed time."""
        rates, _ = self._rates(hour)
        return rates.get(self.tile_of(x_m, y_m), 0.0)

    def density_ahead(
        self, path_xy: npt.ArrayLike, corridor_m: float = 2.0, hour: int | None = None
    ) -> float:
        """Expected RF-detected road users per hour passing through a corridor along a path.

        ``path_xy`` is the vehicle's path ahead, ``(n, 2)`` points in metres
        (n ≥ 1; a polyline). Every tile whose centre lies within
        ``corridor_m + tile_m/√2`` of the polyline contributes its visit rate
        once. With :attr:`hourly` and ``hour`` given the rate is the one of
        that hour of day.

        Raises:
            ConfigError: a path that is not (n, 2) or a negative corridor.
        """
        path = np.asarray(path_xy, dtype=np.float64)
        if path.ndim != 2 or path.shape[1] != 2 or len(path) < 1:
            raise ConfigError(f"density_ahead: path must be (n, 2) points, got {path.shape}")
        if corridor_m < 0:
            raise ConfigError(f"density_ahead: corridor_m must be >= 0, got {corridor_m}")
        rates, _ = self._rates(hour)
        if not rates:
            return 0.0
        s = self.config.tile_m
        reach = corridor_m + s / math.sqrt(2.0)
        keys = list(rates)
        centres = (np.array(keys, dtype=np.float64) + 0.5) * s
        dist = _distance_to_polyline(centres, path)
        return float(sum(rates[k] for k, d in zip(keys, dist, strict=True) if d <= reach))

    # -- persistence ---------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready contents: settings, times, observed time and per-tile counts
        decayed to the newest record. No emitter ids."""
        factor = self._decay_to(None)
        return {
            "format": FORMAT,
            "version": VERSION,
            "config": asdict(self.config),
            "first_ns": self.first_ns,
            "last_ns": self.last_ns,
            "observed_s": [float(v) for v in self._exposure * factor],
            "tiles": [
                [k[0], k[1], [float(v) for v in self._counts[k] * factor]] for k in self.tiles()
            ],
        }

    def save(self, path: str | Path) -> Path:
        """Write the prior as JSON, atomically (a small file: one line per tile's 24 counts).

        Raises:
            DataFormatError: the file cannot be written.
        """
        out = Path(path)
        data = self.to_dict()
        lines = [json.dumps({k: v for k, v in data.items() if k != "tiles"})[:-1] + ', "tiles": [']
        lines += [
            "  " + json.dumps(t) + ("," if i < len(data["tiles"]) - 1 else "")
            for i, t in enumerate(data["tiles"])
        ]
        lines.append("]}")
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=out.name, suffix=".tmp")
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write("\n".join(lines) + "\n")
            os.replace(tmp, out)
        except OSError as err:
            raise DataFormatError(f"{out}: cannot write the activity prior: {err}") from err
        return out

    @classmethod
    def load(cls, path: str | Path) -> ActivityPrior:
        """Read a prior written by :meth:`save`; counting continues from where it stopped.

        Raises:
            DataFormatError: unreadable file, not JSON, another format or a bad field
                (named with the file).
        """
        p = Path(path)
        try:
            data = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError) as err:
            raise DataFormatError(f"{p}: cannot read the activity prior: {err}") from err
        except json.JSONDecodeError as err:
            raise DataFormatError(f"{p}: not JSON (line {err.lineno}): {err.msg}") from err
        return cls.from_dict(data, str(p))

    @classmethod
    def from_dict(cls, data: Any, where: str = "prior") -> ActivityPrior:
        """Rebuild a prior from :meth:`to_dict`'s mapping.

        Raises:
            DataFormatError: another format or version, or a missing or bad field.
        """
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise DataFormatError(f"{where}: not an activity prior (format must be {FORMAT!r})")
        if data.get("version") != VERSION:
            raise DataFormatError(f"{where}: unsupported version {data.get('version')!r}")
        try:
            config = PriorConfig(**data["config"])
            prior = cls(config)
            first, last = data["first_ns"], data["last_ns"]
            prior.first_ns = None if first is None else int(first)
            prior.last_ns = None if last is None else int(last)
            prior._ref_ns = prior.last_ns
            prior._exposure = _hours(data["observed_s"], "observed_s")
            for i, entry in enumerate(data["tiles"]):
                ix, iy, counts = entry
                prior._counts[(int(ix), int(iy))] = _hours(counts, f"tiles[{i}]")
        except (KeyError, TypeError, ValueError, ConfigError) as err:
            raise DataFormatError(f"{where}: bad activity prior field: {err}") from err
        return prior


class PriorSink:
    """A result sink that keeps a prior file up to date across backend runs.

    Opens ``path`` (or starts an empty prior when it does not exist), counts
    every step's trustworthy fixes and writes the file back on :meth:`close`
    (which :meth:`BackendService.close` calls).

    Raises:
        DataFormatError: ``path`` exists but is not an activity prior.
    """

    def __init__(self, path: str | Path, config: PriorConfig | None = None) -> None:
        self.path = Path(path)
        self.prior = ActivityPrior.load(self.path) if self.path.exists() else ActivityPrior(config)

    def on_results(self, fixes: Sequence[Fix], assessments: Sequence[Assessment]) -> None:
        """Count the step's trustworthy fixes."""
        self.prior.on_results(fixes, assessments)

    def close(self) -> None:
        """Forget the in-memory emitter table and save the prior."""
        self.prior.close()
        self.prior.save(self.path)


def _hours(values: Any, name: str) -> Array:
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (HOURS,) or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"{name} must be {HOURS} finite values >= 0")
    return arr


def _distance_to_polyline(points: Array, path: Array) -> Array:
    """Shortest distance of each point (m, 2) to the polyline ``path`` (n, 2), metres."""
    if len(path) == 1:
        return np.asarray(np.hypot(*(points - path[0]).T), dtype=np.float64)
    a = path[:-1][None, :, :]
    b = path[1:][None, :, :]
    p = points[:, None, :]
    ab = b - a
    denom = np.maximum(np.sum(ab * ab, axis=2), 1e-12)
    u = np.clip(np.sum((p - a) * ab, axis=2) / denom, 0.0, 1.0)
    nearest = a + u[..., None] * ab
    d = np.hypot(*(p - nearest).transpose(2, 0, 1))
    return np.asarray(d.min(axis=1), dtype=np.float64)
