"""ITS time: ``TimestampIts``, TAI milliseconds since the ITS epoch.

The ITS epoch is 2004-01-01T00:00:00.000 UTC (ETSI TS 102 894-2, ``TimestampIts``).
The count is of elapsed SI milliseconds, so every leap second UTC inserted since
the epoch adds one second to it: 2007-01-01T00:00:00 UTC is 94 694 401 000 ms
(the standard's own example, one leap second after the epoch). rfsas-hw clocks
are UTC nanoseconds (POSIX time, which does not count leap seconds).
"""

from __future__ import annotations

import bisect

__all__ = ["ITS_EPOCH_UTC_NS", "LEAP_SECONDS_UTC_NS", "its_ms_from_utc_ns", "utc_ns_from_its_ms"]

NS_PER_MS = 1_000_000
NS_PER_S = 1_000_000_000

ITS_EPOCH_UTC_NS = 1_072_915_200 * NS_PER_S
"""2004-01-01T00:00:00 UTC as POSIX nanoseconds."""

LEAP_SECONDS_UTC_NS: tuple[int, ...] = tuple(
    s * NS_PER_S
    for s in (
        1_136_073_600,  # 2006-01-01: the leap second of 2005-12-31 23:59:60
        1_230_768_000,  # 2009-01-01
        1_341_100_800,  # 2012-07-01
        1_435_708_800,  # 2015-07-01
        1_483_228_800,  # 2017-01-01
    )
)
"""POSIX time of the first instant after each leap second inserted since the ITS epoch
(IERS Bulletin C; none has been announced after 2016-12-31)."""


def _leaps_before(utc_ns: int) -> int:
    return bisect.bisect_right(LEAP_SECONDS_UTC_NS, utc_ns)


def its_ms_from_utc_ns(utc_ns: int) -> int:
    """``TimestampIts`` (ms) of a UTC time in POSIX nanoseconds (rounded down to the ms).

    Raises:
        ValueError: the time is before the ITS epoch.
    """
    if utc_ns < ITS_EPOCH_UTC_NS:
        raise ValueError(f"time {utc_ns} ns is before the ITS epoch (2004-01-01 UTC)")
    elapsed_ns = utc_ns - ITS_EPOCH_UTC_NS + _leaps_before(utc_ns) * NS_PER_S
    return elapsed_ns // NS_PER_MS


def utc_ns_from_its_ms(its_ms: int) -> int:
    """The UTC time (POSIX nanoseconds) of a ``TimestampIts`` in ms.

    A time inside an inserted leap second maps to the first instant after it (POSIX
    time cannot name the 61st second).

    Raises:
        ValueError: a negative timestamp.
    """
    if its_ms < 0:
        raise ValueError(f"TimestampIts {its_ms} is negative")
    t = ITS_EPOCH_UTC_NS + its_ms * NS_PER_MS
    leaps = 0
    for i, leap in enumerate(LEAP_SECONDS_UTC_NS):
        # on the elapsed scale, leap second i spans [leap + i s, leap + (i + 1) s)
        if t >= leap + (i + 1) * NS_PER_S:
            leaps = i + 1
        elif t >= leap + i * NS_PER_S:
            return leap
        else:
            break
    return t - leaps * NS_PER_S
