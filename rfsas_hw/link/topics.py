"""The broker topic contract (version 1) and the quadkey tiles it is partitioned by.

Topics (every level separated by ``/``; ids are ``[A-Za-z0-9._-]{1,32}``)::

    rfsas/v1/bearing/<sensor-id>/<q1>/<q2>/…/<q16>   signed safety messages, QoS 0
    rfsas/v1/advisory/<q1>/…/<q16>                   the backend's signed assessments, QoS 0
    rfsas/v1/vehicle/<vehicle-id>/advisory            the same, addressed to one vehicle
    rfsas/v1/nonce/<receiver-id>/<epoch>             nonce envelopes, retained, QoS 1,
                                                     MQTT 5 message expiry at the end of
                                                     the epoch's grace period

``q1 … q16`` are the digits (0–3) of the zoom-16 quadkey of the tile that holds
the sender's position (about 600 m × 600 m at the equator, less towards the
poles), one topic level per digit, so ``rfsas/v1/bearing/+/1/2/0/#`` takes every
sensor in one zoom-3 tile. Tiles follow the Web-Mercator quadkey scheme (the
one Bing Maps and the C-ITS geomessaging pilots use): digit = x bit + 2·y bit,
most significant first, y growing southwards.

The payload is always the signed datagram, byte for byte; the broker is not
trusted, so a receiver checks that the sensor id in a bearing topic equals the
signed sender id (:func:`topic_sender`).
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import LinkError
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.privacy.nonces import NonceEnvelopeError, parse_envelope

ROOT = "rfsas/v1"
"""Prefix of every topic of this contract version."""
ZOOM = 16
"""Quadkey zoom level of the tiles in topics."""
MAX_LAT_DEG = 85.05112878
"""Latitude limit of the Web-Mercator tiling, degrees."""
_ID_RE = re.compile(r"[A-Za-z0-9._-]{1,32}")
_QUADKEY_RE = re.compile(r"[0-3]{1,23}")
_POSE_XY = struct.Struct(">ff")
_TYPE_SAFETY = 1
_TYPE_NONCE = 2


def quadkey(lat_deg: float, lon_deg: float, zoom: int = ZOOM) -> str:
    """The quadkey of the Web-Mercator tile at ``zoom`` that holds (``lat_deg``, ``lon_deg``).

    Latitudes beyond ±85.05° are clamped to the tiling's edge.

    Raises:
        LinkError: a non-finite coordinate or a zoom outside 1–23.
    """
    return quadkeys(np.array([lat_deg]), np.array([lon_deg]), zoom)[0]


def quadkeys(lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, zoom: int = ZOOM) -> list[str]:
    """:func:`quadkey` of many positions at once (arrays broadcast), in their order.

    The tile indices are computed as arrays and each distinct tile is spelt once, so
    hundreds of vehicles in a few tiles cost little more than a few.

    Raises:
        LinkError: a non-finite coordinate or a zoom outside 1–23.
    """
    lat, lon = np.broadcast_arrays(
        np.asarray(lat_deg, dtype=np.float64), np.asarray(lon_deg, dtype=np.float64)
    )
    lat, lon = lat.ravel(), lon.ravel()
    finite = np.isfinite(lat) & np.isfinite(lon)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise LinkError(f"cannot tile a non-finite position ({lat[i]}, {lon[i]})")
    if not 1 <= zoom <= 23:
        raise LinkError(f"quadkey zoom {zoom} outside 1-23")
    n = 1 << zoom
    s = np.sin(np.radians(np.clip(lat, -MAX_LAT_DEG, MAX_LAT_DEG)))
    x = ((lon + 180.0) / 360.0 * n).astype(np.int64)
    y = ((0.5 - np.log((1 + s) / (1 - s)) / (4 * math.pi)) * n).astype(np.int64)
    tile = np.clip(x, 0, n - 1) * n + np.clip(y, 0, n - 1)
    spelt: dict[int, str] = {}
    for t in set(tile.tolist()):
        tx, ty = divmod(t, n)
        spelt[t] = "".join(
            str((1 if tx & (1 << i) else 0) + (2 if ty & (1 << i) else 0))
            for i in range(zoom - 1, -1, -1)
        )
    return [spelt[t] for t in tile.tolist()]


def check_quadkey(key: str) -> str:
    """``key`` if it is a quadkey (1–23 digits 0–3).

    Raises:
        LinkError: it is not.
    """
    if not _QUADKEY_RE.fullmatch(key):
        raise LinkError(f"{key!r} is not a quadkey (1-23 digits 0-3)")
    return key


def _levels(key: str) -> str:
    return "/".join(check_quadkey(key))


def _check_id(ident: str, what: str) -> str:
    if not _ID_RE.fullmatch(ident):
        raise LinkError(f"{what} id {ident!r} must be 1-32 of A-Z a-z 0-9 . _ -")
    return ident


def bearing_topic(sensor_id: str, tile: str) -> str:
    """``rfsas/v1/bearing/<sensor-id>/<digit>/…`` of a sensor in ``tile``.

    Raises:
        LinkError: a bad id or quadkey.
    """
    return f"{ROOT}/bearing/{_check_id(sensor_id, 'sensor')}/{_levels(tile)}"


def bearing_filter(tile: str | None = None, sensor_id: str | None = None) -> str:
    """Subscription filter for the bearings of one sensor and/or every sensor in ``tile``
    (a quadkey of any zoom ≤ 16; None: everywhere).

    Raises:
        LinkError: a bad id or quadkey.
    """
    who = "+" if sensor_id is None else _check_id(sensor_id, "sensor")
    where = "#" if tile is None else f"{_levels(tile)}/#" if len(tile) < ZOOM else _levels(tile)
    return f"{ROOT}/bearing/{who}/{where}"


def advisory_topic(tile: str) -> str:
    """``rfsas/v1/advisory/<digit>/…`` for assessments of emitters in ``tile``.

    Raises:
        LinkError: a bad quadkey.
    """
    return f"{ROOT}/advisory/{_levels(tile)}"


def advisory_filter(tile: str | None = None) -> str:
    """Subscription filter for the advisories of ``tile`` (any zoom; None: everywhere).

    Raises:
        LinkError: a bad quadkey.
    """
    if tile is None:
        return f"{ROOT}/advisory/#"
    return f"{ROOT}/advisory/{_levels(tile)}" + ("/#" if len(tile) < ZOOM else "")


def vehicle_topic(vehicle_id: str) -> str:
    """``rfsas/v1/vehicle/<vehicle-id>/advisory``.

    Raises:
        LinkError: a bad id.
    """
    return f"{ROOT}/vehicle/{_check_id(vehicle_id, 'vehicle')}/advisory"


def nonce_topic(receiver_id: str, epoch: int) -> str:
    """``rfsas/v1/nonce/<receiver-id>/<epoch>``.

    Raises:
        LinkError: a bad id or a negative epoch.
    """
    if epoch < 0:
        raise LinkError(f"epoch {epoch} is negative")
    return f"{ROOT}/nonce/{_check_id(receiver_id, 'receiver')}/{epoch}"


def nonce_filter(receiver_id: str) -> str:
    """Subscription filter for every nonce envelope addressed to ``receiver_id``.

    Raises:
        LinkError: a bad id.
    """
    return f"{ROOT}/nonce/{_check_id(receiver_id, 'receiver')}/+"


def topic_sender(topic: str) -> str | None:
    """The sensor id a bearing topic names, or None for a topic that names no sender."""
    prefix = f"{ROOT}/bearing/"
    if not topic.startswith(prefix):
        return None
    return topic[len(prefix) :].split("/", 1)[0]


@dataclass(frozen=True, slots=True)
class Route:
    """Where and how one datagram is published."""

    topic: str
    qos: int = 0
    retain: bool = False
    expiry_s: int | None = None
    """MQTT 5 message expiry interval, seconds (None: the message does not expire)."""


class TopicRouter:
    """Chooses the topic of a datagram by the contract above.

    Safety messages go to their sender's bearing topic in the tile of the
    sender's position (local metres placed on the globe by ``origin``); nonce
    envelopes to their receiver's nonce topic, retained until the end of the
    epoch's grace period.

    Args:
        origin: the site origin; None: bearings cannot be routed (an error names it).
        schedule: the deployment's epochs, for the nonce expiry.
    """

    def __init__(self, origin: SiteOrigin | None, schedule: EpochSchedule | None = None) -> None:
        self.origin = origin
        self.schedule = schedule or EpochSchedule()
        self._tiles: dict[tuple[float, float], str] = {}
        self._bearing_routes: dict[bytes, Route] = {}
        """Route of a safety message by its sender id and position bytes: a sensor
        publishes from one place, so its topic is made and checked once."""

    def tile_of(self, x_m: float, y_m: float) -> str:
        """The zoom-16 quadkey of local position (``x_m`` east, ``y_m`` north), metres.

        Raises:
            LinkError: no site origin is configured.
        """
        key = (x_m, y_m)
        tile = self._tiles.get(key)
        if tile is None:
            if self.origin is None:
                raise LinkError(
                    "bearing topics need the site origin (latitude, longitude) to find the "
                    "tile: add origin=LAT,LON to the mqtt URL"
                )
            lat, lon, _ = self.origin.to_geodetic(x_m, y_m)
            tile = quadkey(float(lat), float(lon))
            if len(self._tiles) > 1024:
                self._tiles.clear()
            self._tiles[key] = tile
        return tile

    def route(self, datagram: bytes, now_ns: int) -> Route:
        """The route of ``datagram`` (a signed safety message or a nonce envelope).

        Raises:
            LinkError: the datagram is of another kind or too short to route, or
                bearings cannot be placed without a site origin.
        """
        if len(datagram) < 6 or datagram[:2] != b"RF":
            raise LinkError("not an rfsas datagram; nothing to route it by")
        kind = datagram[3]
        if kind == _TYPE_SAFETY:
            n = datagram[5]
            at = 6 + n + 20
            if len(datagram) < at + 8:
                raise LinkError("safety message too short to route")
            key = bytes(datagram[5 : 6 + n]) + bytes(datagram[at : at + 8])
            route = self._bearing_routes.get(key)
            if route is None:
                sender = datagram[6 : 6 + n].decode("ascii", "replace")
                x_m, y_m = _POSE_XY.unpack_from(datagram, at)
                route = Route(bearing_topic(sender, self.tile_of(x_m, y_m)))
                if len(self._bearing_routes) > 1024:
                    self._bearing_routes.clear()
                self._bearing_routes[key] = route
            return route
        if kind == _TYPE_NONCE:
            try:
                env = parse_envelope(datagram)
            except NonceEnvelopeError as err:
                raise LinkError(f"cannot route a nonce envelope: {err}") from err
            end_ns = self.schedule.start_ns(env.epoch + 1) + self.schedule.grace_ns
            expiry = max(1, math.ceil((end_ns - now_ns) / 1e9))
            return Route(nonce_topic(env.receiver_id, env.epoch), 1, True, expiry)
        raise LinkError(f"message type {kind} has no default topic; publish it to a topic")
