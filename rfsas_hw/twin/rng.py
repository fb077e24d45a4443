"""Named random streams: one seed, independent generators per purpose.

Each part of the simulation draws from its own stream, keyed by stable names
(``("traffic", "phone-1")``), so adding an emitter or a sensor does not change
what the others draw, and the same seed always gives the same numbers.
"""

from __future__ import annotations

import zlib

import numpy as np


def stream(seed: int, *names: str) -> np.random.Generator:
    """The generator for ``names`` under ``seed`` (stable across runs and platforms)."""
    keys = [zlib.crc32(n.encode("utf-8")) for n in names]
    return np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFF_FFFF, *keys]))
