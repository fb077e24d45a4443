"""The dashboard in a real browser: ``rfsas backend --web`` fed the demo's captures live.

Debian's Chromium, headless, driven by its chromedriver through selenium. The page must
show the sensors and a fix with its ellipse, switch to BRAKE when the demo does, come
back by itself after the server restarts, and never show a raw MAC. A screenshot is
kept as a test artefact (``RFSAS_SCREENSHOT=path.png`` also copies it there).
"""

from __future__ import annotations

import http.server
import math
import os
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import urllib.request
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from rfsas_hw.link.keys import KeyStore
from rfsas_hw.studies.demo import EXAMPLE_SCENARIO, DemoResult, run_demo

from .replay import LiveReplay

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
SKIP_REASON = (
    "needs Debian's chromium and chromium-driver (/usr/bin/chromium, /usr/bin/chromedriver)"
)
ORIGIN = "52.2053,0.1218,12"
MAP_SCRIPT = """
const q = (s) => Array.from(document.querySelectorAll(s));
return {
  sensors: q("#layer-sensors path.sensor").map((e) => e.dataset.id),
  fov: q("#layer-fov path.fov").length,
  fixes: q("#layer-fixes circle.fix").map((e) => e.dataset.emitter),
  ellipses: q("#layer-fixes ellipse.ellipse").map(
    (e) => [e.dataset.emitter, +e.getAttribute("rx"), +e.getAttribute("ry")]),
  vehicle: q("#layer-vehicle rect.vehicle").length,
  links: q("#links tbody tr").map((e) => e.dataset.sensor),
  emitters: document.getElementById("emitters").innerText,
};
"""

pytestmark = pytest.mark.skipif(
    not (CHROMIUM.exists() and CHROMEDRIVER.exists()), reason=SKIP_REASON
)


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for(check: Callable[[], Any], timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def http_ok(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=1.0) as r:
            return bool(r.status == 200)
    except OSError:
        return False


def one_pixel_png(rgb: tuple[int, int, int]) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = struct.pack(">I", zlib.crc32(kind + data))
        return struct.pack(">I", len(data)) + kind + data + crc

    header = struct.pack(">IIBBBBB", 1, 1, 8, 2, 0, 0, 0)
    pixels = zlib.compress(b"\x00" + bytes(rgb))
    body = chunk(b"IHDR", header) + chunk(b"IDAT", pixels) + chunk(b"IEND", b"")
    return b"\x89PNG\r\n\x1a\n" + body


@pytest.fixture
def tile_server() -> Iterator[tuple[str, list[tuple[str, str | None]]]]:
    """A map tile server on loopback: every tile is one pale pixel; requests are recorded."""
    asked: list[tuple[str, str | None]] = []
    tile = one_pixel_png((250, 250, 247))  # the page's own background colour

    class Tiles(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            asked.append((self.path, self.headers.get("Referer")))
            self.send_response(200)
            self.send_header("Content-Type", "image/png")
            self.send_header("Content-Length", str(len(tile)))
            self.end_headers()
            self.wfile.write(tile)

        def log_message(self, *args: Any) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Tiles)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/{{z}}/{{x}}/{{y}}.png", asked
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


@pytest.fixture
def browser(tmp_path: Path) -> Iterator[Any]:
    webdriver = pytest.importorskip(
        "selenium.webdriver", reason="needs the dev extra: pip install 'rfsas-hw[dev]'"
    )
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for arg in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--window-size=1280,800",
        f"--user-data-dir={tmp_path / 'chromium-profile'}",
    ):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=opts)
    driver.set_page_load_timeout(15)
    try:
        yield driver
    finally:
        driver.quit()


@pytest.mark.extra("web")
def test_dashboard_live_in_a_browser(
    tmp_path: Path, browser: Any, tile_server: tuple[str, list[tuple[str, str | None]]]
) -> None:
    from selenium.webdriver.common.by import By

    demo: DemoResult = run_demo(out_dir=tmp_path / "demo", plot=False)
    assert demo.first_brake_s is not None
    backend_keys = KeyStore.create(tmp_path / "backend", "backend", "obu-1")
    stores = {}
    for sid in ("rsu-nw", "car-obu"):
        stores[sid] = KeyStore.create(tmp_path / sid, "sensor", sid)
        backend_keys.trust.enroll(stores[sid].card)
    config = tmp_path / "backend.yaml"
    config.write_text(
        "site:\n"
        f"  map: {EXAMPLE_SCENARIO}\n"
        f"  tiles: {tile_server[0]}\n"
        "  sensors:\n"
        "    rsu-nw: {x_m: -9.0, y_m: 9.0, heading_deg: 140.0, fov_deg: 60}\n"
    )
    listen = f"udp://127.0.0.1:{free_port(socket.SOCK_DGRAM)}"
    vehicle = f"udp://127.0.0.1:{free_port(socket.SOCK_DGRAM)}"
    web_port = free_port(socket.SOCK_STREAM)
    url = f"http://127.0.0.1:{web_port}/"
    args = [
        sys.executable, "-m", "rfsas_hw.cli.main", "backend", "--listen", listen,
        "--keys", str(tmp_path / "backend"), "--vehicle", vehicle, "--reaction", "0.5",
        "--config", str(config), "--origin", ORIGIN, "--web", f"127.0.0.1:{web_port}",
        "--no-table", "--out", str(tmp_path / "run.jsonl"), "--duration", "60",
        "--force",  # the restart below writes the run log again
    ]  # fmt: skip

    logs: list[Path] = []

    def start_backend() -> subprocess.Popen[bytes]:
        logs.append(tmp_path / f"backend-{len(logs)}.log")
        with logs[-1].open("wb") as log:
            proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=log)
        wait_for(lambda: http_ok(url + "api/site") or proc.poll() is not None, 20, "backend")
        assert proc.poll() is None, logs[-1].read_text()
        return proc

    proc = start_backend()
    try:
        browser.get(url)
        status = browser.find_element(By.ID, "status")
        wait_for(lambda: status.get_attribute("data-status") == "live", 10, "the page to go live")
        # the site map came from the scenario: four buildings and two roads
        assert len(browser.find_elements(By.CSS_SELECTOR, "#layer-site path.building")) == 4
        # tiles under it, from the site's tile server, the one under the origin among them;
        # the page's address (which may hold the token) is never sent along
        asked = wait_for(lambda: list(tile_server[1]), 10, "map tiles")
        tiles = {tuple(map(int, re.findall(r"\d+", path))) for path, _ in asked}
        z = next(iter(tiles))[0]
        lat = math.radians(52.2053)
        x0 = int((0.1218 + 180) / 360 * 2**z)
        y0 = int((1 - math.log(math.tan(lat) + 1 / math.cos(lat)) / math.pi) / 2 * 2**z)
        assert 15 <= z <= 19 and (z, x0, y0) in tiles
        assert all(referer is None for _, referer in asked)

        replay = LiveReplay(demo, stores, listen, vehicle)
        replay.start()
        seen: list[tuple[float, str, str]] = []
        advisory = browser.find_element(By.ID, "advisory")
        shot = tmp_path / "dashboard.png"
        while replay.thread.is_alive():
            seen.append((replay.t_s, advisory.get_attribute("data-advisory") or "", advisory.text))
            if seen[-1][1] == "brake" and not shot.exists():
                assert browser.save_screenshot(str(shot))  # the moment that matters
            time.sleep(0.05)
        replay.join(5)

        brake = [(t, text) for t, a, text in seen if a == "brake"]
        assert brake, f"the page never showed BRAKE; saw {sorted({a for _, a, _ in seen})}"
        # the demo's first BRAKE came at demo.first_brake_s of scenario time; live steps and
        # the browser's polling add up to a few tenths of a second either way
        assert abs(brake[0][0] - demo.first_brake_s) <= 1.0, (brake[0], demo.first_brake_s)
        assert brake[0][1] == "BRAKE"
        # before it, the page showed the calmer advisories the demo gave then
        assert {a for t, a, _ in seen if t < demo.first_brake_s - 1.0} <= {
            "none",
            "clear",
            "caution",
        }

        # read the map in one go: the page redraws it at every backend step
        page = browser.execute_script(MAP_SCRIPT)
        assert set(page["sensors"]) == {"rsu-nw", "car-obu"}
        assert page["fov"] == 2
        assert page["fixes"] and page["ellipses"]
        assert {e[0] for e in page["ellipses"]} <= set(page["fixes"])
        assert all(rx >= ry > 0 for _, rx, ry in page["ellipses"])
        assert page["vehicle"] == 1
        assert set(page["links"]) == {"rsu-nw", "car-obu"}
        # real-world coordinates next to each fix
        assert "52.20" in page["emitters"]

        assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        if os.environ.get("RFSAS_SCREENSHOT"):
            shutil.copy(shot, os.environ["RFSAS_SCREENSHOT"])

        macs = [e.mac.lower() for e in demo.scenario.spec.emitters]
        with urllib.request.urlopen(url + "api/state", timeout=2) as r:
            served = r.read().decode().lower()
        # the run log (now with bearing lines) holds hashes only, too
        logged = (tmp_path / "run.jsonl").read_text().lower()
        for text in (browser.page_source.lower(), served, logged):
            for mac in macs:
                assert mac not in text and mac.replace(":", "") not in text

        # restart the server: the page notices, and comes back by itself
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(15) in (0, 130, 143)
        wait_for(lambda: status.get_attribute("data-status") == "reconnecting", 10, "reconnecting")
        proc = start_backend()
        wait_for(lambda: status.get_attribute("data-status") == "live", 10, "reconnection")
        assert len(browser.find_elements(By.CSS_SELECTOR, "#layer-site path.building")) == 4
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)


PAGE_SCRIPT = """
const q = (s) => Array.from(document.querySelectorAll(s));
const fix = document.querySelector("#layer-fixes circle.fix");
const box = fix ? fix.getBoundingClientRect() : null;
const top = box ? document.elementFromPoint(box.x + box.width / 2, box.y + box.height / 2) : null;
const label = document.querySelector("#map text.label");
const map = document.getElementById("map");
const vb = map.viewBox.baseVal, mb = map.getBoundingClientRect();
const bar = document.getElementById("scalebar");
return {
  status: document.getElementById("status").dataset.status,
  advisory: document.getElementById("advisory").dataset.advisory,
  stale: document.getElementById("advisory").dataset.stale,
  banner: document.getElementById("advisory").innerText,
  fixes: q("#layer-fixes circle.fix").map((e) => e.dataset.emitter),
  emitters: q("#emitters tbody tr td:first-child").map((e) => e.innerText),
  on_top: top ? top.tagName + "." + top.getAttribute("class") : null,
  label_box: label ? Object.values(label.getBoundingClientRect().toJSON()) : null,
  fix_box: box ? Object.values(box.toJSON()) : null,
  px_per_m: Math.min(mb.width / vb.width, mb.height / vb.height),
  scale_m: +bar.dataset.metres, scale_px: +bar.dataset.px,
  north: document.getElementById("north").innerText,
  ticks: q("#timeline text.tick-label").map((e) => e.textContent),
};
"""


@pytest.mark.extra("web")
def test_the_page_draws_its_first_state_and_reads_as_a_map(browser: Any) -> None:
    """Without the live feed (the page is opened without the token the WebSocket asks):
    the served first state is drawn; a scale bar, a north arrow, a time axis; the fix
    over a sensor's label; 16-hex emitter ids; no advisory once every link is silent."""
    from rfsas_hw.backend.site import SiteConfig, SiteSensor
    from rfsas_hw.records import Assessment, Fix, Pose
    from rfsas_hw.web import site_payload
    from rfsas_hw.web.server import DashboardServer
    from rfsas_hw.web.state import DashboardState

    ns = 1_000_000_000
    now = [1_767_268_800 * ns]
    emitter = "0123456789abcdef"
    links = [{"sensor_id": "rsu-a", "state": "ok", "messages": 3, "lost": 0}]
    site = SiteConfig(
        sensors=(
            SiteSensor("rsu-a", Pose(0.0, 0.0, 90.0), 60.0),
            SiteSensor("rsu-b", Pose(60.0, 0.0, 270.0), 60.0),
        )
    )
    state = DashboardState(site, clock=lambda: now[0], link_health=lambda: links)

    def step(advisory: str) -> None:
        t = now[0]
        # where rsu-a's name is written: up and right of the sensor
        fx = Fix(t, emitter, 3.0, 1.9, 0.04, 0.0, 0.04, True, "ok", "", ("rsu-a", "rsu-b"), 1, 1)
        judged = Assessment(
            t, emitter, 3.0, 1.9, 0.0, 0.0, 0.2, 0.2, 0.0, 0.1, ("rsu-a", "rsu-b"), True, "",
            0.1, 1.0, 5.0, 10.0, 0.02, 0.02, advisory, (), False,
        )  # fmt: skip
        state.on_results([fx], [judged])
        now[0] += ns // 10

    for _ in range(300):  # 30 s of steps
        step("caution")
    server = DashboardServer(state, site_payload(site), "127.0.0.1", 0, token="s3cret")
    server.start()
    try:
        browser.get(f"http://127.0.0.1:{server.port}/")
        page = browser.execute_script(PAGE_SCRIPT)
        assert page["status"] != "live"  # the WebSocket was refused: all came with the page
        assert page["advisory"] == "caution" and page["stale"] == "no"
        assert page["fixes"] == [emitter] and page["emitters"] == [emitter]
        # the label is drawn where the fix is, and the fix is in front of it
        lx, ly, lw, lh = page["label_box"][:4]
        fx, fy, fw, fh = page["fix_box"][:4]
        assert lx < fx + fw / 2 < lx + lw and ly < fy + fh / 2 < ly + lh, page
        assert page["on_top"] == "circle.fix"
        # a round scale bar length, drawn at the map's own metres per pixel
        assert page["scale_m"] in {1, 2, 5, 10, 20, 50, 100}
        assert page["scale_px"] == pytest.approx(page["scale_m"] * page["px_per_m"], abs=0.1)
        assert 30 <= page["scale_px"] <= 100
        assert "N" in page["north"]
        # 30 s on the timeline: ticks every 10 s back from now
        assert page["ticks"] == ["now", "−10 s", "−20 s"]

        links[0] = {"sensor_id": "rsu-a", "state": "silent", "messages": 3, "lost": 0}
        step("caution")
        browser.refresh()
        page = browser.execute_script(PAGE_SCRIPT)
        assert page["stale"] == "yes" and page["advisory"] == "none"
        assert "CAUTION" not in page["banner"] and "NO DATA" in page["banner"]
    finally:
        server.stop()
