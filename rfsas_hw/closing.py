"""Objects that a ``with`` block closes."""

from __future__ import annotations

from types import TracebackType
from typing import Self

__all__ = ["ClosingContext"]


class ClosingContext:
    """Mixin: ``with obj:`` gives ``obj`` and calls its :meth:`close` on the way out,
    whether the block ended or raised (an exception is not swallowed)."""

    __slots__ = ()

    def close(self) -> object:
        """Release what the object holds; each class implements it, idempotent.

        Raises:
            NotImplementedError: the class did not implement it.
        """
        raise NotImplementedError(f"{type(self).__name__}.close")

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
