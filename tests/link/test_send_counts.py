"""Cue and advisory senders count what they sent, what failed and what the broker
refused, and say so when nothing got through (the summaries of ``live``/``replay
--send-cues``, ``backend --send-cues`` and ``backend --advise``)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.backend.cuer import BackendCuer
from rfsas_hw.backend.service import BackendService
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.errors import LinkError
from rfsas_hw.fleet.advisory import AdvisorySink
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link.cue_publisher import CuePublisher
from rfsas_hw.link.sendcount import send_problem
from rfsas_hw.link.signing import Signer
from rfsas_hw.link.topics import Route, TopicRouter
from rfsas_hw.link.transport import FanoutTransport, Transport
from rfsas_hw.records import BearingBatch, Pose
from rfsas_hw.stream import Fanout

sys.path.insert(0, str(Path(__file__).parents[1] / "fleet"))
from test_advisory_limits import assessment

NOW_NS = 1_763_800_030_000_000_000


class Link(Transport):
    """Sends (or fails to), and reports ``refusing`` of what it sent as refused."""

    def __init__(self, fail: bool = False, refusing: bool = False) -> None:
        self.fail, self.refusing, self.sent = fail, refusing, 0

    def send(self, datagram: bytes) -> None:
        if self.fail:
            raise LinkError("udp://192.0.2.1:9: cannot send: network unreachable")
        self.sent += 1

    def publish(self, route: Route, datagram: bytes) -> None:
        self.send(datagram)

    def refused(self) -> int:
        return self.sent if self.refusing else 0

    def recv(self, timeout: float | None = None) -> bytes | None:
        return None

    def close(self) -> None:
        pass


def signer() -> Signer:
    return Signer("unit-1", ec.derive_private_key(0x4242, ec.SECP256R1()))


def bearings(t_ns: int, emitters: list[int]) -> BearingBatch:
    n = len(emitters)
    return BearingBatch(
        sensor_id="rsu-1",
        t_ns=np.full(n, t_ns, np.int64),
        azimuth_deg=np.full(n, 30.0),
        sigma_deg=np.full(n, 2.0),
        snr_db=np.full(n, 20.0),
        channel=np.full(n, 6, np.int16),
        emitter=np.array(emitters, np.uint64),
    )


def cue_run(link: Link) -> Fanout:
    pub = CuePublisher(signer(), link, Pose(0.0, 0.0, 0.0), clock=lambda: NOW_NS)
    fanout = Fanout([pub])
    pub.on_bearings(bearings(NOW_NS, [1, 2, 3]))
    pub.on_bearings(bearings(NOW_NS + 100_000_000, [1]))  # too soon: not a cue
    fanout.close()
    return fanout


def test_a_sensors_cues_are_counted_in_its_summary() -> None:
    fanout = cue_run(Link())
    ((name, counts),) = fanout.counters().items()
    assert name == "send cues Link"
    assert counts == {"sent": 3, "failed": 0, "refused": 0, "dropped.rate": 1}
    assert fanout.problems() == []


def test_cues_that_all_failed_or_were_refused_are_a_problem() -> None:
    failing = cue_run(Link(fail=True))
    # a cue not sent is tried again with the emitter's next bearing
    assert failing.counters()["send cues Link"]["failed"] == 4
    assert failing.problems() == [
        "send cues Link: none of 4 cues got through (4 send errors, 0 refused by the broker)"
    ]
    refused = cue_run(Link(refusing=True))
    assert refused.counters()["send cues Link"]["refused"] == 3
    assert "none of 3 cues got through (0 send errors, 3 refused" in refused.problems()[0]


def test_send_problem_only_when_nothing_got_through() -> None:
    assert send_problem("cues", 0, 0, 0) is None  # nothing to send
    assert send_problem("cues", 5, 2, 0) is None  # an outage ridden out
    assert send_problem("cues", 5, 0, 4) is None  # one got through
    assert send_problem("cues", 0, 2, 0) is not None
    assert send_problem("cues", 4, 0, 4) is not None


def test_refusals_add_up_over_a_fanout() -> None:
    a, b = Link(refusing=True), Link(refusing=True)
    both = FanoutTransport({"a": a, "b": b})
    both.send(b"x")
    assert both.refused() == 2


def backend_with_cues(link: Link) -> tuple[BackendService, BackendCuer]:
    cuer = BackendCuer(signer(), link, clock=lambda: NOW_NS)
    service = BackendService(sinks=[cuer], clock=lambda: NOW_NS)
    for sid, x in (("rsu-a", -20.0), ("rsu-b", 20.0)):
        az = math.degrees(math.atan2(1.0 - x, 0.0 - 10.0)) % 360.0  # towards (1, 0)
        service.on_bearings(
            BearingBatch(
                sid,
                np.array([NOW_NS - 50_000_000], np.int64),
                np.array([az]),
                np.array([2.0]),
                np.array([20.0]),
                np.array([6], np.int16),
                np.array([0x0123456789ABCDEF], np.uint64),
            ),
            Pose(x, 10.0, 180.0),
        )
    service.set_vehicle(VehicleState(x_m=1.75, y_m=-40.0, heading_deg=0.0, speed_mps=15.0))
    service.step(NOW_NS)
    return service, cuer


def test_the_backends_cues_are_counted_and_a_failing_link_is_a_problem() -> None:
    service, cuer = backend_with_cues(Link())
    assert cuer.counters()["sent"] == 1 and service.problems() == []
    service, cuer = backend_with_cues(Link(fail=True))
    assert cuer.counters()["sent"] == 0 and cuer.counters()["failed"] == 1
    assert service.problems() == [
        "BackendCuer: none of 1 cues got through (1 send errors, 0 refused by the broker)"
    ]


def test_advisories_are_counted_and_refused_ones_are_a_problem() -> None:
    router = TopicRouter(SiteOrigin(48.137, 11.575))

    def run(link: Link) -> AdvisorySink:
        out = AdvisorySink(signer(), link, router, router.tile_of(0, 0), vehicle_id="car-7")
        out.on_results([], [assessment(1), assessment(2, "brake")])
        return out

    fine = run(Link())
    # one message on the emitters' tile, one on the vehicle's topic
    assert fine.counters() == {"sent": 2, "failed": 0, "refused": 0}
    assert fine.problem() is None
    failing = run(Link(fail=True))
    assert failing.counters() == {"sent": 0, "failed": 2, "refused": 0}
    assert failing.problem() is not None
    refused = run(Link(refusing=True))
    assert refused.counters()["refused"] == 2
    assert "2 refused by the broker" in (refused.problem() or "")
