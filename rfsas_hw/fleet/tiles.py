"""Which backends own which tiles: disjoint tile sets, each run by an active/active group.

A plan in YAML::

    groups:
      north: {tiles: ["1202", "1203"], members: [be-a, be-b]}   # an active/active pair
      south: {tiles: ["1212"], members: [be-c, be-d]}

Tiles are quadkeys of any zoom up to 16 (a short quadkey is the region of all
its sub-tiles). Regions of different groups must not overlap, so every
sensor's stream goes to exactly one group and association never splits it;
every member of a group subscribes to all of the group's tiles and computes
the same outputs, so losing one member loses nothing. A backend is a member
of one group at most.

MQTT shared subscriptions (``$share/…``) hand successive messages to different
members: they split one sensor's stream, so use them only for stateless
consumers such as a recorder, never for association.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rfsas_hw.config import read_yaml
from rfsas_hw.errors import ConfigError, LinkError
from rfsas_hw.link.message import check_sender_id
from rfsas_hw.link.topics import ZOOM, bearing_filter, check_quadkey


@dataclass(frozen=True, slots=True)
class TileGroup:
    """Backends that all serve the same tiles."""

    name: str
    tiles: tuple[str, ...]
    """Quadkeys (zoom ≤ 16) of the region the group owns."""
    members: tuple[str, ...]
    """Backend ids, every one subscribed to every tile of the group."""

    def filters(self) -> list[str]:
        """The bearing subscriptions of every member."""
        return [bearing_filter(t) for t in self.tiles]

    def owns(self, tile: str) -> bool:
        """True when ``tile`` (a quadkey) lies in the group's region."""
        return any(tile.startswith(t) for t in self.tiles)


class TilePlan:
    """Groups of backends with disjoint tile regions.

    Raises:
        ConfigError: overlapping regions, a backend in two groups, an empty group,
            a bad quadkey or id.
    """

    def __init__(self, groups: Iterable[TileGroup], where: str = "tile plan") -> None:
        self.groups = {g.name: g for g in groups}
        self.where = where
        self._check()

    def _check(self) -> None:
        seen_member: dict[str, str] = {}
        owned: list[tuple[str, str]] = []
        for g in self.groups.values():
            if not g.tiles or not g.members:
                raise ConfigError(f"{self.where}: group {g.name!r} needs tiles and members")
            for m in g.members:
                if m in seen_member:
                    first = seen_member[m]
                    raise ConfigError(
                        f"{self.where}: backend {m!r} is in groups {first!r} and {g.name!r}"
                    )
                seen_member[m] = g.name
            for t in g.tiles:
                for other_group, other in owned:
                    if other_group != g.name and (t.startswith(other) or other.startswith(t)):
                        raise ConfigError(
                            f"{self.where}: tile {t} of {g.name!r} overlaps tile {other} of "
                            f"{other_group!r}; regions must be disjoint so no sensor's stream "
                            "is split between groups"
                        )
                owned.append((g.name, t))

    @classmethod
    def from_mapping(cls, data: Any, where: str) -> TilePlan:
        """Parse ``{groups: {NAME: {tiles: [...], members: [...]}}}``.

        Raises:
            ConfigError: the shape or a value is wrong (the message names the key).
        """
        if not isinstance(data, Mapping) or set(data) != {"groups"}:
            raise ConfigError(f"{where}: expected a mapping with the one key 'groups'")
        raw_groups = data["groups"]
        if not isinstance(raw_groups, Mapping) or not raw_groups:
            raise ConfigError(f"{where}: groups must map group names to tiles and members")
        groups = []
        for name, spec in raw_groups.items():
            at = f"{where}: groups.{name}"
            if not isinstance(spec, Mapping) or set(spec) != {"tiles", "members"}:
                raise ConfigError(f"{at}: expected exactly the keys tiles and members")
            tiles, members = spec["tiles"], spec["members"]
            if not isinstance(tiles, list) or not isinstance(members, list):
                raise ConfigError(f"{at}: tiles and members must be lists")
            try:
                checked = tuple(check_quadkey(str(t)) for t in tiles)
                for m in members:
                    check_sender_id(str(m))
            except LinkError as err:
                raise ConfigError(f"{at}: {err}") from err
            if any(len(t) > ZOOM for t in checked):
                raise ConfigError(f"{at}: tiles must be quadkeys of zoom {ZOOM} or less")
            groups.append(TileGroup(str(name), checked, tuple(str(m) for m in members)))
        return cls(groups, where)

    def group_of(self, backend_id: str) -> TileGroup:
        """The group ``backend_id`` belongs to.

        Raises:
            ConfigError: it belongs to none.
        """
        for g in self.groups.values():
            if backend_id in g.members:
                return g
        raise ConfigError(f"{self.where}: backend {backend_id!r} is in no group")

    def owner(self, tile: str) -> TileGroup | None:
        """The group whose region holds ``tile`` (a zoom-16 quadkey), or None."""
        for g in self.groups.values():
            if g.owns(tile):
                return g
        return None

    def listen_options(self, backend_id: str) -> dict[str, str]:
        """The ``tiles=`` option of ``backend_id``'s broker URL.

        Raises:
            ConfigError: it belongs to no group.
        """
        return {"tiles": ",".join(self.group_of(backend_id).tiles)}


def load_tile_plan(path: str | Path) -> TilePlan:
    """Read a tile plan from YAML.

    Raises:
        ConfigError: unreadable file, invalid YAML or plan.
    """
    return TilePlan.from_mapping(read_yaml(path), str(path))


def assign_tiles(tiles: Sequence[str], groups: Sequence[str]) -> dict[str, list[str]]:
    """Spread ``tiles`` over ``groups`` by rendezvous hashing: each tile goes to the
    group with the highest hash of (group, tile), so adding or removing a group
    moves only the tiles that group gains or loses.

    Raises:
        ConfigError: no groups, or a bad quadkey.
    """
    if not groups:
        raise ConfigError("no backend groups to assign tiles to")
    out: dict[str, list[str]] = {g: [] for g in groups}
    for tile in tiles:
        try:
            check_quadkey(tile)
        except LinkError as err:
            raise ConfigError(str(err)) from err

        def score(group: str, tile: str = tile) -> bytes:
            return hashlib.sha256(f"{group}\0{tile}".encode()).digest()

        out[max(groups, key=score)].append(tile)
    return out


def with_tiles(url: str, plan: TilePlan, backend_id: str) -> str:
    """``url`` with the ``tiles=`` of ``backend_id``'s group added, when it is a broker
    URL (``mqtt://``, ``mqtts://``) that names no tiles or subscriptions of its own;
    other URLs are returned unchanged.

    Raises:
        ConfigError: the backend is in no group of the plan.
    """
    if not url.startswith(("mqtt://", "mqtts://")):
        return url
    if "tiles=" in url or "sub=" in url:
        raise ConfigError(f"{url!r}: give the tiles by the plan or in the URL, not both")
    tiles = plan.listen_options(backend_id)["tiles"]
    return f"{url}{'&' if '?' in url else '?'}tiles={tiles}"
