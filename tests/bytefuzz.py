"""Byte mutations shared by the binary fuzz tests (link datagrams, CPMs, board streams,
captures, IQ payloads).

A mutation takes a random generator, the bytes to mutate and a pool of valid inputs
(for splices) and returns new bytes; it never mutates its input. The fixed ones are
plain functions; those a test tunes (which bytes count as header, how far to extend,
what junk looks like) are made by the factories below. :func:`mutate` applies a few
drawn from a list; a test weights a mutation by listing it more than once.
"""

from __future__ import annotations

import random
import struct
from collections.abc import Callable, Sequence

Mutation = Callable[[random.Random, bytes, Sequence[bytes]], bytes]

INTERESTING_U32 = (0, 1, 3, 4, 8, 12, 0x7F, 0x80, 0xFF, 0xFFFF, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF)
"""Length and count values where parsers go wrong (both byte orders are tried)."""


def flip_bits(rng: random.Random, d: bytes, _: Sequence[bytes]) -> bytes:
    """One to eight bit flips anywhere."""
    b = bytearray(d)
    for _i in range(rng.choice((1, 1, 2, 3, 8))):
        if b:
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
    return bytes(b)


def truncate(rng: random.Random, d: bytes, _: Sequence[bytes]) -> bytes:
    """Cut at a random length (possibly to nothing)."""
    return d[: rng.randrange(len(d) + 1)]


def insert(rng: random.Random, d: bytes, _: Sequence[bytes]) -> bytes:
    """1-31 random bytes inserted anywhere."""
    pos = rng.randrange(len(d) + 1)
    return d[:pos] + rng.randbytes(rng.randint(1, 31)) + d[pos:]


def delete(rng: random.Random, d: bytes, _: Sequence[bytes]) -> bytes:
    """1-31 bytes deleted anywhere."""
    pos = rng.randrange(len(d) + 1)
    return d[:pos] + d[pos + rng.randint(1, 31) :]


def splice(rng: random.Random, d: bytes, pool: Sequence[bytes]) -> bytes:
    """This input's head on the tail of another from the pool."""
    other = rng.choice(pool)
    cut = rng.randrange(len(d) + 1)
    return d[:cut] + other[rng.randrange(len(other) + 1) :]


def duplicate(rng: random.Random, d: bytes, _: Sequence[bytes]) -> bytes:
    """A piece of the input (up to 60 bytes) copied in again elsewhere."""
    if not d:
        return d
    start = rng.randrange(len(d))
    piece = d[start : start + rng.randint(1, 60)]
    pos = rng.randrange(len(d) + 1)
    return d[:pos] + piece + d[pos:]


def pack_u32(rng: random.Random, d: bytes, _: Sequence[bytes]) -> bytes:
    """An :data:`INTERESTING_U32` value written over four bytes, little or big endian."""
    if len(d) < 4:
        return d
    b = bytearray(d)
    struct.pack_into(
        rng.choice("<>") + "I", b, rng.randrange(len(b) - 3), rng.choice(INTERESTING_U32)
    )
    return bytes(b)


def set_byte(header: int = 48, values: bytes = b"\x00\x01\x7f\x80\xff") -> Mutation:
    """A byte set to one of ``values`` or a random one; 60 % of the time within the
    first ``header`` bytes, where parsers read lengths and types."""

    def mutation(rng: random.Random, d: bytes, _: Sequence[bytes]) -> bytes:
        if not d:
            return d
        b = bytearray(d)
        pos = rng.randrange(min(len(b), header)) if rng.random() < 0.6 else rng.randrange(len(b))
        b[pos] = rng.choice(values) if rng.random() < 0.8 else rng.randrange(256)
        return bytes(b)

    return mutation


def extend(sizes: Sequence[int] = (1, 2, 30, 64, 1500)) -> Mutation:
    """Random bytes appended, as many as one of ``sizes``."""

    def mutation(rng: random.Random, d: bytes, _: Sequence[bytes]) -> bytes:
        return d + rng.randbytes(rng.choice(sizes))

    return mutation


def junk(heads: Sequence[bytes] = (b"",), longest: int = 400) -> Mutation:
    """Random bytes (0 to ``longest``) replacing the input, half the time behind one of
    ``heads`` (a valid magic or type, so the parser reads further)."""

    def mutation(rng: random.Random, d: bytes, _: Sequence[bytes]) -> bytes:
        head = rng.choice(heads) if rng.random() < 0.5 else b""
        return head + rng.randbytes(rng.randrange(longest + 1))

    return mutation


def mutate(
    rng: random.Random,
    data: bytes,
    mutations: Sequence[Mutation],
    pool: Sequence[bytes] = (),
    rounds: Sequence[int] = (1,),
) -> bytes:
    """``data`` after as many mutations as one of ``rounds``, each drawn from ``mutations``."""
    for _ in range(rng.choice(rounds)):
        data = rng.choice(mutations)(rng, data, pool or (data,))
    return data
