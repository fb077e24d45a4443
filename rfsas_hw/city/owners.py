"""Which backend owns each vehicle now, and which owned it lately.

A vehicle belongs to the backend of the tile it is in (:mod:`rfsas_hw.city.partition`).
An advisory judged by the backend of a tile the vehicle left a moment ago is still
its owner's (it was judged there and was on its way): :class:`VehicleOwners` keeps,
per vehicle, its backend and tile now and those it left within ``memory_s``.

Each step costs one comparison per vehicle: only a vehicle whose backend or tile
changed since the previous step is written (at 500 vehicles, a vehicle crosses
into another tile in a few steps of a thousand).
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["VehicleOwners"]


class VehicleOwners:
    """Per vehicle, its backend and tile now, and those it left lately (module docstring).

    Args:
        memory_s: how long after a vehicle left a tile its backend still counts as its
            owner, seconds (simulation time).
    """

    def __init__(self, memory_s: float) -> None:
        self.memory_s = memory_s
        self._now: dict[str, tuple[str | None, str]] = {}
        """Per vehicle, (backend or None for a tile nobody owns, tile) at its last step."""
        self._left: dict[str, dict[tuple[str | None, str], float]] = {}
        """Per vehicle, the (backend, tile) it left, with the last step it was there, sim s."""
        self._t_s = 0.0
        """Time of the last :meth:`update`, sim s."""

    def update(
        self,
        t_s: float,
        vehicles: Sequence[str],
        backends: Sequence[str | None],
        tiles: Sequence[str],
    ) -> None:
        """The vehicles at ``t_s``: each one's backend (None: a tile nobody owns) and tile.
        A vehicle not given keeps what it had."""
        now = self._now
        prev_t = self._t_s
        for vid, where in zip(vehicles, zip(backends, tiles, strict=True), strict=True):
            was = now.get(vid)
            if was == where:
                continue
            now[vid] = where
            if was is None:
                continue
            left = self._left.setdefault(vid, {})
            left[was] = prev_t
            left.pop(where, None)  # back in a tile it left: it is its tile now
        self._t_s = t_s

    def _lately(self, vid: str, t_s: float) -> list[tuple[str | None, str]]:
        """(backend, tile) pairs the vehicle left within the memory, oldest first, and now."""
        out: list[tuple[str | None, str]] = []
        left = self._left.get(vid)
        if left:
            oldest = t_s - self.memory_s
            for where, last_s in list(left.items()):
                if last_s < oldest:
                    del left[where]
                else:
                    out.append(where)
        now = self._now.get(vid)
        if now is not None:
            out.append(now)
        return out

    def owns(self, backend: str, vid: str, t_s: float | None = None) -> bool:
        """Whether ``backend`` owns ``vid`` at ``t_s`` (default: the last update), or did
        within the memory."""
        lately = self._lately(vid, self._t_s if t_s is None else t_s)
        return any(b == backend for b, _ in lately)

    def tiles(self, vid: str, t_s: float | None = None) -> tuple[str, ...]:
        """The tiles ``vid`` was in within the memory up to ``t_s`` (default: the last
        update), the one it is in last."""
        lately = self._lately(vid, self._t_s if t_s is None else t_s)
        return tuple(dict.fromkeys(t for _, t in lately))
