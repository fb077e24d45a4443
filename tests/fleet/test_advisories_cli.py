"""``rfsas advisories``: a vehicle verifies the backends' advisories through the broker."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
from brokerhelp import Broker, Deployment
from fleethelp import ORIGIN

from rfsas_hw.fleet.advisory import AdvisorySink
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link.keys import TrustDir
from rfsas_hw.records import Assessment

NAN = float("nan")


def assessment(t_ns: int) -> Assessment:
    return Assessment(
        t_ns=t_ns, emitter="00000000000000aa", x_m=12.0, y_m=30.0, cov_xx_m2=1.0,
        cov_xy_m2=0.0, cov_yy_m2=1.0, vx_mps=0.0, vy_mps=1.0, age_s=0.1, sensors=("rsu-1",),
        fix_ok=True, fix_reason="", p_collision=0.5, t_closest_s=2.0,
        distance_to_contact_m=15.0, impact_speed_mps=6.0, fatality_risk=0.1, risk=0.05,
        advisory="brake", reasons=(), link_alarm=False,
    )  # fmt: skip


def test_vehicle_command_prints_verified_advisories(
    broker: Broker, deployment: Deployment, tmp_path: Path
) -> None:
    trust = TrustDir(tmp_path / "trust")
    trust.enroll(deployment.backends["be-a"].card)
    lat, lon = (float(v) for v in ORIGIN.split(","))
    sink = AdvisorySink.to_url(
        broker.url("be-a"), deployment.backends["be-a"].signer(), SiteOrigin(lat, lon),
        vehicle_id="car-7",
    )  # fmt: skip
    cmd = [sys.executable, "-m", "rfsas_hw.cli.main", "advisories", "--json"]
    cmd += ["--listen", broker.url("car-7", sub="rfsas/v1/vehicle/car-7/advisory")]
    cmd += ["--trust", str(trust.path), "--vehicle-id", "car-7", "--duration", "8"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        while proc.poll() is None:
            sink.on_results([], [assessment(time.time_ns())])
            time.sleep(0.2)
        out, err = proc.communicate(timeout=10)
    finally:
        sink.close()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err.decode()
    lines = [json.loads(line) for line in out.decode().splitlines()]
    items, stats = lines[:-1], lines[-1]["stats"]
    assert items and all(i["advisory"] == "brake" and i["backend"] == "be-a" for i in items)
    assert items[0]["x_m"] == 12.0 and items[0]["emitter"] == "00000000000000aa"
    assert stats["verified"] == len(items) and stats["datagrams"] == len(items)


def test_a_broker_url_with_no_advisory_subscription_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Without sub= (or advisories=) the vehicle would subscribe to bearings and hear
    no advisory, exiting 0: refused at start instead, before any connection."""
    from rfsas_hw.cli.main import main
    from rfsas_hw.fleet.advisory import check_advisory_urls
    from rfsas_hw.link.keys import KeyStore

    trust = tmp_path / "trust"
    trust.mkdir()
    backend = KeyStore.create(tmp_path / "be-a", "backend", "be-a")
    (trust / "be-a.yaml").write_bytes((tmp_path / "be-a" / "identity.yaml").read_bytes())
    for urls in (
        ["mqtt://127.0.0.1:9"],
        ["mqtt://127.0.0.1:9?tiles=1202"],
        ["mqtt://127.0.0.1:9?nonces=car-7"],
        ["udp://127.0.0.1:0", "mqtt://127.0.0.1:9"],
    ):
        listen = [a for url in urls for a in ("--listen", url)]
        with pytest.raises(SystemExit) as exc:
            main(["advisories", *listen, "--trust", str(trust), "--duration", "0.1"])
        err = " ".join(capsys.readouterr().err.split())
        assert exc.value.code == 2, (urls, err)
        assert "subscribes to no advisory topic" in err
        assert "sub=rfsas/v1/vehicle/ID/advisory" in err
    # these can carry advisories (checked without connecting)
    check_advisory_urls(
        [
            "mqtt://127.0.0.1:9?sub=rfsas/v1/vehicle/car-7/advisory",
            "mqtt://127.0.0.1:9?advisories=1202",
            "mqtt://127.0.0.1:9?sub=rfsas/v1/%23",
            "udp://127.0.0.1:0",
        ]
    )
    assert backend.id == "be-a"
