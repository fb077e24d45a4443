"""Every vulnerable road user counts: collisions and gaps of the ego against each VRU class.

VRUs are SUMO persons and the two-wheelers SUMO knows by vehicle class
(:data:`VRU_VCLASSES`). Per step, :meth:`VruScore.update` measures the gap
between the ego's box and every VRU's box (oriented rectangles,
:mod:`rfsas_hw.bridges.boxes`), keeps the smallest per class, and marks a
collision when the boxes touch. SUMO's own collision list is cross-checked:
whoever saw the collision (``boxes``, ``sumo``) is recorded. Whether a
collision SUMO alone saw counts is the caller's choice: on SUMO lanes it does
(its list is then the reference); for VRUs placed off the lanes by
``moveToXY`` SUMO maps them onto the nearest lane and reports contacts up to
about a metre early, so there the boxes decide.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from rfsas_hw.bridges.boxes import box_distance, reach
from rfsas_hw.bridges.bridge import Entity

VRU_VCLASSES: tuple[str, ...] = ("bicycle", "moped", "motorcycle")
"""SUMO vehicle classes counted as vulnerable road users (besides persons)."""
PERSON = "pedestrian"
"""The class name of a SUMO person."""
PERSON_PREFIX = "person:"
"""The prefix the SUMO adapter gives person ids."""

__all__ = ["PERSON", "VRU_VCLASSES", "VruScore", "vru_class"]


def vru_class(kind: str, vclass: str | None) -> str | None:
    """The VRU class of an entity (``pedestrian``, ``bicycle``, ``moped``,
    ``motorcycle``), or None when it is not a VRU.

    Args:
        kind: the entity's kind (``pedestrian``, ``cyclist``, ``vehicle``).
        vclass: SUMO's vehicle class of a vehicle (None for a person or unknown).
    """
    if kind == "pedestrian":
        return PERSON
    if vclass in VRU_VCLASSES:
        return vclass
    if kind == "cyclist":
        return "bicycle"
    return None


@dataclass
class VruScore:
    """The ego against every VRU of one run (see the module docstring)."""

    sumo_counts: bool = True
    """Whether a collision only SUMO's list saw counts."""
    collision: bool = False
    """The ego hit a VRU."""
    collision_class: str | None = None
    """The VRU class it hit."""
    collision_with: str | None = None
    """The simulator id of the VRU it hit."""
    seen_by: list[str] = field(default_factory=list)
    """``boxes`` and/or ``sumo``: who saw the collision."""
    min_gap_m: float = math.inf
    """Smallest distance between the ego's box and any VRU's box, metres."""
    min_gap_by_class: dict[str, float] = field(default_factory=dict)
    """The same per VRU class, metres."""

    def update(
        self,
        ego_id: str,
        ego: Entity,
        vrus: Sequence[tuple[Entity, str]],
        collisions: Iterable[object] = (),
    ) -> bool:
        """Measure one step; whether a collision counts now.

        Args:
            ego_id: the ego's SUMO id.
            ego: the ego's box.
            vrus: every VRU now, with its class (:func:`vru_class`).
            collisions: SUMO's ``simulation.getCollisions()`` of this step.
        """
        touching: dict[str, str] = {}
        for v, cls in vrus:
            known = self.min_gap_by_class.get(cls, math.inf)
            if math.hypot(v.x_m - ego.x_m, v.y_m - ego.y_m) - reach(ego, v) > known:
                continue  # even the boxes' closest possible gap is above the smallest so far
            gap = box_distance(ego, v)
            self.min_gap_m = min(self.min_gap_m, gap)
            self.min_gap_by_class[cls] = min(self.min_gap_by_class.get(cls, math.inf), gap)
            if gap == 0.0:
                touching[v.id] = cls
        classes = {v.id.removeprefix(PERSON_PREFIX): (v.id, cls) for v, cls in vrus}
        by_sumo: dict[str, str] = {}
        for c in collisions:
            collider, victim = str(getattr(c, "collider", "")), str(getattr(c, "victim", ""))
            other = victim if collider == ego_id else collider if victim == ego_id else None
            if other is not None and other in classes:
                eid, cls = classes[other]
                by_sumo[eid] = cls
        if not touching and not (by_sumo and self.sumo_counts):
            if by_sumo and "sumo" not in self.seen_by:
                self.seen_by.append("sumo")  # a contact SUMO alone reported, kept for the record
            return False
        self.collision = True
        self.seen_by = sorted(
            {*self.seen_by, *(["boxes"] if touching else []), *(["sumo"] if by_sumo else [])}
        )
        who = {**by_sumo, **touching}
        self.collision_with, self.collision_class = next(iter(who.items()))
        return True
