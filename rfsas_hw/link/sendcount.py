"""How a sender of signed messages (cues, advisories) reports what it sent.

One rule for every such sender, so that a run's summary counts the same way
everywhere: ``sent`` (handed to the carrier without error), ``failed`` (the
carrier raised), ``refused`` (sent, then refused by the far end: an MQTT broker's
negative acknowledgement), and what was not sent for another reason as
``dropped.REASON``. The run failed when something was to be sent and nothing got
through: every attempt failed, or the broker refused all that was sent.
"""

from __future__ import annotations

from collections.abc import Mapping

__all__ = ["send_counters", "send_problem"]


def send_counters(
    sent: int, failed: int, refused: int, dropped: Mapping[str, int] | None = None
) -> dict[str, int]:
    """The flat counters of a sender: ``sent``, ``failed``, ``refused``, ``dropped.*``."""
    out = {"sent": sent, "failed": failed, "refused": refused}
    out.update({f"dropped.{k}": v for k, v in sorted((dropped or {}).items()) if v})
    return out


def send_problem(what: str, sent: int, failed: int, refused: int) -> str | None:
    """Why nothing of ``what`` (e.g. ``cues``) got through, or None when something did
    or nothing was to be sent. A refused message was first counted as sent."""
    attempted = sent + failed
    if attempted == 0 or sent > refused:
        return None
    return (
        f"none of {attempted:,} {what} got through "
        f"({failed:,} send errors, {refused:,} refused by the broker)"
    )
