"""The base class every capture source derives from.

A driver implements only :meth:`Source._read_raw` (and, if it holds resources,
:meth:`Source._close`). The base class does the rest: the error policy,
counters, filtering, iteration, close-once, context management, and a
``ResourceWarning`` for a source that was never closed.
"""

from __future__ import annotations

import logging
import warnings
from abc import ABC, abstractmethod
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, ClassVar, Generic, Literal, TypeVar

import numpy as np
import numpy.typing as npt

from rfsas_hw.closing import ClosingContext
from rfsas_hw.errors import RfsasError
from rfsas_hw.records import BearingBatch, ObservationBatch

log = logging.getLogger(__name__)

ErrorPolicy = Literal["raise", "skip"]


BatchT = TypeVar("BatchT", ObservationBatch, BearingBatch)
BatchFilter = Callable[[Any], npt.NDArray[np.bool_]]

MAX_KEPT_ERRORS = 20


@dataclass
class SourceStats:
    """Counters a source keeps while it runs; the CLI prints them at the end."""

    frames: int = 0
    """Frames read from the underlying input (before filtering)."""
    observations: int = 0
    """Observations yielded (after filtering)."""
    batches: int = 0
    """Non-empty batches yielded."""
    filtered: int = 0
    """Observations removed by the source's filter."""
    skipped: Counter[str] = field(default_factory=Counter)
    """Frames or records dropped, by reason."""
    errors: list[str] = field(default_factory=list)
    """The first few error messages (with file/frame/offset), for the summary."""
    extra: dict[str, Any] = field(default_factory=dict)
    """Driver-specific counters (pairing rate, CRC errors, reconnects, …)."""

    def skip(self, reason: str, message: str | None = None, count: int = 1) -> None:
        """Count ``count`` dropped items under ``reason``; keep the message if room."""
        self.skipped[reason] += count
        if message is not None and len(self.errors) < MAX_KEPT_ERRORS:
            self.errors.append(message)

    def as_dict(self) -> dict[str, Any]:
        """A JSON-friendly copy."""
        return {
            "frames": self.frames,
            "observations": self.observations,
            "batches": self.batches,
            "filtered": self.filtered,
            "skipped": dict(self.skipped),
            "errors": list(self.errors),
            **self.extra,
        }


class Source(ClosingContext, ABC, Generic[BatchT]):
    """A stream of batches from a capture, a device or a model.

    Most sources yield :class:`ObservationBatch` (raw MAC + RSSI per antenna);
    a source of finished bearings (a Doppler DF unit) yields
    :class:`BearingBatch`.

    Use as a context manager and iterate::

        with rfsas_hw.sources.open("pcap:capture.pcap") as src:
            for batch in src:
                ...

    Args:
        errors: ``"skip"`` (default) drops a bad frame, counts it in
            ``stats.skipped`` and goes on; ``"raise"`` raises the error.
        filter: optional function returning a keep-mask for each batch.
    """

    scheme: ClassVar[str] = ""
    """The spec prefix this driver is registered under (``pcap``, ``wifi``, …)."""
    yields_bearings: ClassVar[bool] = False
    """True for sources of finished bearings (no calibration or DF needed)."""

    def __init__(self, *, errors: ErrorPolicy = "skip", filter: BatchFilter | None = None) -> None:
        if errors not in ("raise", "skip"):
            raise ValueError(f"error policy must be 'raise' or 'skip', not {errors!r}")
        self.error_policy: ErrorPolicy = errors
        self.filter = filter
        self.stats = SourceStats()
        self._closed = False
        self._exhausted = False

    @classmethod
    def from_spec(cls, arg: str, **options: Any) -> Source[Any]:
        """Build the source from the part of the spec after ``scheme:``.

        Drivers whose constructor does not take the argument as its first
        positional parameter override this.
        """
        return cls(arg, **options)  # type: ignore[call-arg, arg-type]

    # -- what drivers implement -------------------------------------------------

    @abstractmethod
    def _read_raw(self, timeout: float | None) -> BatchT | None:
        """Read the next batch from the hardware or file.

        Return None on timeout; call :meth:`_end` and return None at the end
        of the input. Report a bad frame through :meth:`_bad` and go on.
        """

    def _close(self) -> None:
        """Release the driver's resources. Called once."""

    # -- helpers for drivers ----------------------------------------------------

    def _end(self) -> None:
        """Mark the input as exhausted; iteration stops after the current batch."""
        self._exhausted = True

    def _bad(self, reason: str, error: RfsasError) -> None:
        """Apply the error policy to one bad frame or record.

        Raises:
            RfsasError: ``error`` itself under the ``raise`` policy.
        """
        if self.error_policy == "raise":
            raise error
        self.stats.skip(reason, str(error))
        log.debug("skipped (%s): %s", reason, error)

    # -- public API -------------------------------------------------------------

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has run."""
        return self._closed

    @property
    def exhausted(self) -> bool:
        """True when the input has ended (a file fully read, a device gone for good)."""
        return self._exhausted

    def read(self, timeout: float | None = None) -> BatchT | None:
        """The next batch after filtering, or None on timeout or at the end.

        Raises:
            SourceError: the source is closed.
            RfsasError: a bad frame under the ``raise`` error policy.
        """
        if self._closed:
            from rfsas_hw.errors import SourceError

            raise SourceError(f"{self!r} is closed")
        if self._exhausted:
            return None
        batch = self._read_raw(timeout)
        if batch is None:
            return None
        self.stats.frames += len(batch)
        if self.filter is not None and len(batch):
            keep = np.asarray(self.filter(batch), dtype=bool)
            self.stats.filtered += int(len(batch) - keep.sum())
            batch = batch.select(keep)
        self.stats.observations += len(batch)
        if len(batch):
            self.stats.batches += 1
        return batch

    def __iter__(self) -> Iterator[BatchT]:
        """Yield non-empty batches until the input ends or the source is closed."""
        while not self._closed and not self._exhausted:
            batch = self.read()
            if batch is not None and len(batch):
                yield batch

    def close(self) -> None:
        """Release resources. Safe to call more than once."""
        if self._closed:
            return
        self._closed = True
        self._close()

    def __del__(self) -> None:
        if not getattr(self, "_closed", True):
            warnings.warn(
                f"{type(self).__name__} was never closed; use it as a context manager",
                ResourceWarning,
                stacklevel=2,
            )
            self.close()
