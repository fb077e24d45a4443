"""The topic contract: quadkeys, one level per digit, routing, URL parsing."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "link"))

from linkhelp import POSE, key, message

from rfsas_hw.errors import LinkError
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link import Signer
from rfsas_hw.link.mqtt import parse_mqtt_url
from rfsas_hw.link.topics import (
    TopicRouter,
    bearing_filter,
    bearing_topic,
    quadkey,
    quadkeys,
    topic_sender,
)
from rfsas_hw.privacy.nonces import NonceAuthority
from rfsas_hw.records import Pose


def test_quadkey_matches_the_published_tile_scheme() -> None:
    # Bing Maps tile system: level 3 tile (x=3, y=5) is quadkey "213"
    # (its centre: longitude -45 + 22.5 = -22.5, latitude about -55.8)
    assert quadkey(-55.0, -22.5, zoom=3) == "213"
    assert quadkey(85.0, -180.0, zoom=1) == "0"
    assert quadkey(-85.0, 179.9, zoom=1) == "3"
    assert len(quadkey(48.137, 11.575)) == 16
    # a point 10 m away at zoom 16 (≈ 400 m tiles in Munich) lies in the same tile
    assert quadkey(48.137, 11.575)[:14] == quadkey(48.13709, 11.575)[:14]


def test_quadkeys_tile_many_positions_in_order() -> None:
    # the published tiles above, repeated and interleaved: one key per position, in order
    lats = [-55.0, 85.0, -55.0, -85.0]
    lons = [-22.5, -180.0, -22.5, 179.9]
    assert quadkeys(lats, lons, zoom=3) == ["213", "000", "213", "333"]
    assert quadkeys(lats, lons) == [quadkey(a, b) for a, b in zip(lats, lons, strict=True)]
    assert quadkeys([], []) == []
    with pytest.raises(LinkError, match=r"non-finite position \(1.0, inf\)"):
        quadkeys([0.0, 1.0], [0.0, float("inf")])
    with pytest.raises(LinkError, match="zoom 24"):
        quadkeys([0.0], [0.0], zoom=24)


def test_bad_inputs() -> None:
    with pytest.raises(LinkError, match="non-finite"):
        quadkey(float("nan"), 0.0)
    with pytest.raises(LinkError, match="quadkey"):
        bearing_topic("rsu-1", "0124")
    with pytest.raises(LinkError, match="sensor id"):
        bearing_topic("rsu/1", "0123")


def test_filters_take_a_region_with_a_wildcard() -> None:
    assert bearing_filter("120") == "rfsas/v1/bearing/+/1/2/0/#"
    assert bearing_filter() == "rfsas/v1/bearing/+/#"
    assert bearing_filter(sensor_id="rsu-1") == "rfsas/v1/bearing/rsu-1/#"
    assert topic_sender("rfsas/v1/bearing/rsu-1/1/2") == "rsu-1"
    assert topic_sender("rfsas/v1/advisory/1/2") is None


def test_router_places_a_sensor_in_the_tile_of_its_position() -> None:
    origin = SiteOrigin(48.137, 11.575)
    router = TopicRouter(origin)
    raw = Signer("rsu-1", key(0x1234)).encode(message())
    route = router.route(raw, 0)
    lat, lon, _ = origin.to_geodetic(10.0, -20.0)  # the helper message's pose
    assert route.topic == bearing_topic("rsu-1", quadkey(float(lat), float(lon)))
    assert route.qos == 0 and not route.retain
    with pytest.raises(LinkError, match="origin"):
        TopicRouter(None).route(raw, 0)


def test_a_route_made_once_is_that_sender_and_place_only() -> None:
    # the router keeps each sensor's route: messages of other senders, other places and
    # other contents, interleaved, must each still get the topic of their own sender and tile
    origin = SiteOrigin(48.137, 11.575)
    router = TopicRouter(origin)
    far = Pose(3000.0, 2000.0, 90.0)  # kilometres from the helper's pose: another tile
    cases = [
        (sender, pose, seq)
        for seq in (1, 2)
        for sender in ("rsu-1", "rsu-2")
        for pose in (POSE, far)
    ]
    tiles = set()
    for sender, pose, seq in cases:
        raw = Signer(sender, key(0x1234)).encode(message(sender, seq=seq, pose=pose))
        lat, lon, _ = origin.to_geodetic(pose.x_m, pose.y_m)
        tile = quadkey(float(lat), float(lon))
        tiles.add(tile)
        assert router.route(raw, 0).topic == bearing_topic(sender, tile)
    assert len(tiles) == 2


def test_nonce_envelopes_are_retained_until_their_grace_period_ends() -> None:
    from cryptography.hazmat.primitives.asymmetric import x25519

    auth = NonceAuthority("auth-0", x25519.X25519PrivateKey.generate())
    auth.enroll("rsu-1", x25519.X25519PrivateKey.generate().public_key())
    env = auth.seal("rsu-1", 100)
    start_ns = 100 * 60 * 10**9
    route = TopicRouter(None).route(env, start_ns + 30 * 10**9)
    assert route.topic == "rfsas/v1/nonce/rsu-1/100"
    assert route.retain and route.qos == 1 and route.expiry_s == 35


def test_mqtt_urls() -> None:
    ep = parse_mqtt_url("mqtt://broker.example:1884?origin=48.1,11.5&tiles=120,121&nonces=be-a")
    assert (ep.host, ep.port, ep.tls) == ("broker.example", 1884, False)
    assert ep.origin == SiteOrigin(48.1, 11.5)
    assert ep.subscriptions == (
        "rfsas/v1/bearing/+/1/2/0/#",
        "rfsas/v1/bearing/+/1/2/1/#",
        "rfsas/v1/nonce/be-a/+",
    )
    for bad, why in [
        ("mqtt://h?ca=x", "needs mqtts"),
        ("mqtts://h", "needs ca="),
        ("mqtt://h?bogus=1", "unknown option"),
        ("mqtt://h?origin=north", "LAT,LON"),
        ("mqtt://h?tiles=9", "quadkey"),
        ("mqtt://h/some/path", "no path"),
    ]:
        with pytest.raises(LinkError, match=why):
            parse_mqtt_url(bad)
