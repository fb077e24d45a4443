"""Compiled numeric kernels: numba's nopython mode, cached on disk.

A computation that must be fast for one problem as well as for many (a fix, a
collision probability) is written once, as a loop over rows compiled by
:func:`kernel`; the public function validates its inputs with numpy and calls
the kernel for every row at once, so a single call is the batch of one.

Kernel modules import this one; the library imports them when a kernel is first
needed, so that importing :mod:`rfsas_hw` does not import numba. Compiled code
is cached next to the module (or in numba's user cache when that is not
writable): a process pays the compilation once per machine, then only loading
the cache.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

__all__ = ["kernel"]

F = TypeVar("F", bound=Callable[..., Any])


def kernel(fn: F) -> F:
    """``fn`` compiled by numba: nopython, cached on disk, numpy's error model.

    With numpy's error model a float division by zero gives ±inf or NaN, as in
    numpy, instead of raising. No fast-math: IEEE arithmetic, as numpy's.
    """
    return cast(F, numba.njit(cache=True, nogil=True, error_model="numpy")(fn))
