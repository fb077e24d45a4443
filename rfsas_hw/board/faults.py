"""Line faults for the board emulator: garbage, bit flips, dropped bytes, stalls, unplugging.

Faults are applied frame by frame to what the board sends, so the emulator
knows exactly which frames it damaged (:attr:`FaultInjector.touched`); a
receiver that follows the protocol must lose those and only those.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from rfsas_hw.errors import ConfigError


@dataclass(frozen=True)
class Faults:
    """What to break, and how often. All rates are probabilities per frame."""

    garbage: float = 0.0
    """Insert 1–16 random bytes (zeros included) in front of a frame."""
    bitflip: float = 0.0
    """Flip one bit of a frame (its delimiter included)."""
    drop: float = 0.0
    """Drop one byte of a frame (its delimiter included)."""
    stall_every_s: float = 0.0
    """Stop sending for ``stall_s`` every this many seconds (0: never)."""
    stall_s: float = 0.5
    """Length of a stall, seconds."""
    disconnect_every_s: float = 0.0
    """Unplug the board every this many seconds (0: never)."""
    disconnect_s: float = 1.0
    """How long the board stays unplugged, seconds."""
    seed: int = 0
    """Seed of the fault generator."""

    @classmethod
    def parse(cls, specs: list[str] | tuple[str, ...]) -> Faults:
        """Build from ``NAME=VALUE`` strings.

        ``garbage=P``, ``bitflip=P``, ``drop=P``, ``stall=EVERY_S:LENGTH_S``,
        ``disconnect=EVERY_S:DOWN_S``, ``seed=N``.

        Raises:
            ConfigError: unknown name or bad value, naming the spec.
        """
        values: dict[str, float | int] = {}
        for spec in specs:
            name, sep, value = spec.partition("=")
            name = name.strip()
            try:
                if not sep:
                    raise ValueError("expected NAME=VALUE")
                if name in ("garbage", "bitflip", "drop"):
                    p = float(value)
                    if not 0.0 <= p <= 1.0:
                        raise ValueError("a probability must be within 0..1")
                    values[name] = p
                elif name in ("stall", "disconnect"):
                    every, _, length = value.partition(":")
                    values[f"{name}_every_s"] = float(every)
                    if length:
                        values[f"{name}_s"] = float(length)
                elif name == "seed":
                    values["seed"] = int(value)
                else:
                    known = "garbage, bitflip, drop, stall, disconnect, seed"
                    raise ValueError(f"unknown fault (known: {known})")
            except ValueError as err:
                raise ConfigError(f"fault {spec!r}: {err}") from err
        names = {f.name for f in fields(cls)}
        assert set(values) <= names
        return cls(**values)  # type: ignore[arg-type]

    @property
    def any_line_fault(self) -> bool:
        """True when some frames will be damaged or garbage inserted."""
        return self.garbage > 0 or self.bitflip > 0 or self.drop > 0


@dataclass
class FaultInjector:
    """Applies :class:`Faults` to outgoing frames and counts what it did."""

    faults: Faults
    touched: int = 0
    """Frames damaged (bit flipped or byte dropped); each counts once."""
    garbage_bytes: int = 0
    """Random bytes inserted between frames."""
    rng: np.random.Generator = field(init=False)

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.faults.seed)

    def apply(self, frames: list[bytes]) -> bytes:
        """The bytes to put on the line for ``frames``."""
        f = self.faults
        if not f.any_line_fault:
            return b"".join(frames)
        out = bytearray()
        rng = self.rng
        for frame in frames:
            if f.garbage and rng.random() < f.garbage:
                g = rng.integers(0, 256, int(rng.integers(1, 17)), dtype=np.uint8).tobytes()
                out += g
                self.garbage_bytes += len(g)
            damaged = bytearray(frame)
            hit = False
            if f.bitflip and rng.random() < f.bitflip:
                bit = int(rng.integers(0, 8 * len(damaged)))
                damaged[bit // 8] ^= 1 << (bit % 8)
                hit = True
            if f.drop and rng.random() < f.drop:
                del damaged[int(rng.integers(0, len(damaged)))]
                hit = True
            self.touched += hit
            out += damaged
        return bytes(out)
