"""What every sender of cues shares: its counters, its run summary and its transport.

A roadside unit's :class:`~rfsas_hw.link.cue_publisher.CuePublisher` and the
backend's :class:`~rfsas_hw.backend.cuer.BackendCuer` decide differently what
to cue; both count the same way (:mod:`rfsas_hw.link.sendcount`) and close
their transport once.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from rfsas_hw.link.sendcount import send_counters, send_problem
from rfsas_hw.link.transport import Transport

__all__ = ["CueSendStats", "CueSender"]


@dataclass(slots=True)
class CueSendStats:
    """Cues sent, and what was not cued, by reason (``send_error``: the transport raised)."""

    cues: int = 0
    skipped: Counter[str] = field(default_factory=Counter)
    """Reason → count; each sender documents its reasons."""

    def as_dict(self) -> dict[str, int]:
        """Flat counters."""
        out = {"cues": self.cues}
        out.update({f"skipped.{k}": v for k, v in sorted(self.skipped.items())})
        return out


class CueSender:
    """Base of the cue senders: a subclass sets :attr:`stats`, :attr:`transport`
    and ``_closed = False`` when it has opened."""

    stats: CueSendStats
    transport: Transport
    _closed: bool

    def counters(self) -> dict[str, int]:
        """Cues ``sent``, ``failed``, ``refused`` by the broker, and what was not cued as
        ``dropped.REASON`` (:func:`~rfsas_hw.link.sendcount.send_counters`)."""
        st = self.stats
        dropped = {k: v for k, v in st.skipped.items() if k != "send_error"}
        return send_counters(st.cues, st.skipped["send_error"], self.transport.refused(), dropped)

    def problem(self) -> str | None:
        """Why no cue got through, or None (:func:`~rfsas_hw.link.sendcount.send_problem`)."""
        st = self.stats
        return send_problem("cues", st.cues, st.skipped["send_error"], self.transport.refused())

    def close(self) -> None:
        """Close the transport; idempotent."""
        if not self._closed:
            self._closed = True
            self.transport.close()
