"""SumoDistrict: what libsumo's getters give, into the rfsas frame, cars apart from VRUs; each
vehicle's own advisories acted on."""

from __future__ import annotations

from collections import Counter
from types import SimpleNamespace
from typing import Any

import numpy as np

from rfsas_hw.bridges.sumo import SumoControl
from rfsas_hw.city.sumoio import SumoDistrict


class _Domain:
    """One libsumo domain (vehicle or person) of a fake SUMO: static values, each object's
    position, speed, angle and odometer, and a count of every getter's calls."""

    def __init__(self, static: dict[str, tuple[str, float, float]]) -> None:
        self.static = static
        self.values: dict[str, tuple[tuple[float, float], float, float, float]] = {}
        self.calls: Counter[str] = Counter()

    def getVehicleClass(self, oid: str) -> str:  # noqa: N802 (libsumo's name)
        return self.static[oid][0]

    def getLength(self, oid: str) -> float:  # noqa: N802
        return self.static[oid][1]

    def getWidth(self, oid: str) -> float:  # noqa: N802
        return self.static[oid][2]

    def getIDList(self) -> tuple[str, ...]:  # noqa: N802
        self.calls["getIDList"] += 1
        return tuple(self.values)

    def getPosition(self, oid: str) -> tuple[float, float]:  # noqa: N802
        self.calls["getPosition"] += 1
        return self.values[oid][0]

    def getSpeed(self, oid: str) -> float:  # noqa: N802
        self.calls["getSpeed"] += 1
        return self.values[oid][1]

    def getAngle(self, oid: str) -> float:  # noqa: N802
        self.calls["getAngle"] += 1
        return self.values[oid][2]

    def getDistance(self, oid: str) -> float:  # noqa: N802
        self.calls["getDistance"] += 1
        return self.values[oid][3]


class _Steered(_Domain):
    """A vehicle domain that records speed commands."""

    def __init__(self, static: dict[str, tuple[str, float, float]]) -> None:
        super().__init__(static)
        self.values = {oid: ((0.0, 0.0), 10.0, 0.0, 0.0) for oid in static}
        self.commands: list[tuple[str, float]] = []

    def setSpeed(self, oid: str, speed: float) -> None:  # noqa: N802
        self.commands.append((oid, speed))


def _fake_sumo() -> Any:
    vehicle = _Steered(
        {"car": ("passenger", 4.0, 1.8), "bike": ("bicycle", 1.6, 0.6), "bus": ("bus", 12.0, 2.5)}
    )
    person = _Domain({"ped": ("pedestrian", 0.2, 0.5)})
    departed = {"v": ["car", "bike", "bus"], "p": ["ped"]}
    simulation = SimpleNamespace(
        getDepartedIDList=lambda: departed["v"],
        getDepartedPersonIDList=lambda: departed["p"],
        getArrivedIDList=lambda: [],
        getArrivedPersonIDList=lambda: [],
    )
    return SimpleNamespace(vehicle=vehicle, person=person, simulation=simulation, departed=departed)


def test_read_puts_box_centres_in_the_frame_and_vrus_apart() -> None:
    sumo = _fake_sumo()
    sumo.vehicle.values = {
        "car": ((10.0, 20.0), 5.0, 90.0, 30.0),  # heading east
        "bike": ((0.0, 0.0), -1.0, 0.0, 7.0),  # north; SUMO's -1
        "bus": ((-5.0, 0.0), 0.0, 180.0, 0.0),
        "gone": ((0.0, 0.0), 0.0, 0.0, 0.0),  # never departed
    }
    sumo.person.values = {"ped": ((1.0, 2.0), 1.2, 270.0, 0.0)}
    # a frame shifted by (100, 0) m and turned by 0°
    district = SumoDistrict(sumo, lambda x, y: (x + 100.0, y), lambda a: np.asarray(a) % 360.0)
    cars, vrus = district.read()
    assert cars.ids == ("car", "bus") and cars.cls == ("passenger", "bus")
    # a vehicle's front bumper moves back half its length along its heading
    np.testing.assert_allclose(cars.x_m, [110.0 - 2.0, 95.0], atol=1e-9)
    np.testing.assert_allclose(cars.y_m, [20.0, 6.0], atol=1e-9)
    np.testing.assert_allclose(cars.odometer_m, [30.0, 0.0])
    np.testing.assert_allclose(cars.length_m, [4.0, 12.0])
    np.testing.assert_allclose(cars.width_m, [1.8, 2.5])
    # two-wheelers first, then persons; a person's position is its centre
    assert vrus.ids == ("bike", "ped") and vrus.cls == ("bicycle", "pedestrian")
    np.testing.assert_allclose(vrus.x_m, [100.0, 101.0], atol=1e-9)
    np.testing.assert_allclose(vrus.y_m, [-0.8, 2.0], atol=1e-9)
    np.testing.assert_allclose(vrus.heading_deg, [0.0, 270.0])
    np.testing.assert_allclose(vrus.speed_mps, [0.0, 1.2])  # negative speeds clipped
    np.testing.assert_allclose(vrus.odometer_m, [0.0, 0.0])
    # each object is read once; the odometer for vehicles only (each value costs a call)
    assert sumo.vehicle.calls == Counter(
        getIDList=1, getPosition=3, getAngle=3, getSpeed=3, getDistance=2
    )
    assert sumo.person.calls == Counter(getIDList=1, getPosition=1, getAngle=1, getSpeed=1)


def test_read_of_an_empty_simulation_gives_empty_arrays() -> None:
    sumo = _fake_sumo()
    sumo.departed["v"], sumo.departed["p"] = [], []
    sumo.vehicle.values = {}
    cars, vrus = SumoDistrict(sumo, lambda x, y: (x, y), lambda a: np.asarray(a)).read()
    assert len(cars) == len(vrus) == 0
    assert cars.x_m.shape == vrus.speed_mps.shape == (0,)


def test_act_brakes_holds_and_releases_only_the_advised_vehicle() -> None:
    sumo = _fake_sumo()
    district = SumoDistrict(sumo, lambda x, y: (x, y), lambda a: np.asarray(a), SumoControl(1.0))
    district.read()
    listed = sumo.vehicle.calls["getIDList"]
    assert district.act(10.0, "car", "clear") == "none"  # nothing to hand back
    assert district.act(10.0, "car", "brake") == "brake"
    assert sumo.vehicle.commands == [("car", 0.0)]
    assert district.held() == ["car"]
    # held for hold_s after the last BRAKE, whatever else comes; then handed back
    district.release_idle(10.5, set())
    assert district.act(10.9, "car", "clear") == "hold"
    district.release_idle(11.0, {"car"})
    assert district.held() == ["car"]
    district.release_idle(11.1, set())
    assert sumo.vehicle.commands == [("car", 0.0), ("car", -1.0)]
    assert district.held() == []
    # CAUTION after a BRAKE keeps the speed the car came down to
    district.act(12.0, "bus", "brake")
    sumo.vehicle.values["bus"] = ((0.0, 0.0), 2.5, 0.0, 0.0)
    assert district.act(13.5, "bus", "caution") == "cap"
    assert sumo.vehicle.commands[-1] == ("bus", 2.5)
    # acting on a vehicle never asks SUMO for every vehicle's id (a list as long as the
    # traffic, per advisory)
    assert sumo.vehicle.calls["getIDList"] == listed
    # a vehicle that has left the simulation is gone, not an error
    sumo.departed["v"] = []
    sumo.simulation.getArrivedIDList = lambda: ["bus"]
    del sumo.vehicle.values["bus"]
    district.read()
    assert district.act(14.0, "bus", "brake") == "gone"
    assert "bus" not in district.held()
