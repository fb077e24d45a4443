"""Replays the demo's captures into a live backend at the recorded pace, as the sensors would.

The same stages as :func:`rfsas_hw.studies.demo.run_demo` (pcap source, DF pipeline with
each sensor's calibration, keyed hashing shared by both sensors, signed UDP), but on the
wall clock: observation times are shifted to now, so a backend running on real time
associates, triangulates and judges them as it would live ones. The ego vehicle's state
goes to the backend's vehicle feed every step.
"""

from __future__ import annotations

import dataclasses
import json
import threading
import time
from pathlib import Path

import numpy as np

from rfsas_hw.link import Publisher, open_transport
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher
from rfsas_hw.records import ObservationBatch, Pose
from rfsas_hw.sources.pcap import PcapSource
from rfsas_hw.studies.demo import DemoResult
from rfsas_hw.studies.locate import sensor_calibration
from rfsas_hw.twin.rng import stream
from rfsas_hw.twin.world import World

NS = 1_000_000_000


class LiveReplay:
    """Sends the demo's sensors' messages and the car's state in real time (a thread).

    ``t_s`` is the scenario time of the last step sent (−1 before the first).
    """

    def __init__(
        self,
        demo: DemoResult,
        stores: dict[str, KeyStore],
        url: str,
        vehicle_url: str,
        step_s: float = 0.1,
    ) -> None:
        self.world = World(demo.scenario)
        self.spec = demo.scenario.spec
        self.step_s = step_s
        self.t_s = -1.0
        self.error: BaseException | None = None
        key = stream(self.spec.seed, "demo-nonce").bytes(32)
        self.hasher = MacHasher(FixedNonce(key))
        self.obs: dict[str, ObservationBatch] = {}
        self.pipelines: dict[str, SensorPipeline] = {}
        self.publishers: dict[str, Publisher] = {}
        self.pose: dict[str, Pose] = {}
        for sid, store in stores.items():
            with PcapSource(str(demo.files[f"capture {sid}"])) as src:
                self.obs[sid] = ObservationBatch.concat(list(src))
            self.pose[sid] = self._pose(sid, 0.0)
            self.pipelines[sid] = SensorPipeline(
                sensor_calibration(self.world, sid), self.hasher, sid, self.pose[sid]
            )
            self.publishers[sid] = Publisher.to_url(
                url,
                store.signer(),
                (lambda s=sid: self.pose[s]),  # type: ignore[misc]
                epoch_s=self.hasher.epoch_s,
            )
        self.vehicle = open_transport(vehicle_url, "send")
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _pose(self, sid: str, t_s: float) -> Pose:
        xy, heading = self.world.sensor_pose(sid, [t_s])
        return Pose(float(xy[0, 0]), float(xy[0, 1]), float(heading[0]))

    def start(self) -> None:
        self.thread.start()

    def join(self, timeout: float) -> None:
        self.thread.join(timeout)
        if self.error is not None:
            raise self.error

    def _run(self) -> None:
        try:
            self._replay()
        except BaseException as err:  # reported by join()
            self.error = err
        finally:
            for p in self.publishers.values():
                p.close()
            self.vehicle.close()

    def _replay(self) -> None:
        world, spec = self.world, self.spec
        ego = world.tracks[spec.ego or ""]
        length, width = next(m for m in spec.movers if m.id == spec.ego).size_m()
        wall0 = time.time_ns()
        offset = wall0 - world.t0_ns
        cursors = dict.fromkeys(self.obs, 0)
        n_steps = int(np.ceil(world.duration_s / self.step_s))
        for k in range(1, n_steps + 1):
            t_end = world.t0_ns + round(k * self.step_s * NS)
            delay = (t_end + offset - time.time_ns()) / NS
            if delay > 0:
                time.sleep(delay)
            t_s = (t_end - world.t0_ns) / NS
            for sid, obs in self.obs.items():
                stop = int(np.searchsorted(obs.t_ns, t_end, side="left"))
                part = obs.select(slice(cursors[sid], stop))
                cursors[sid] = stop
                if len(part):
                    self.pose[sid] = self._pose(
                        sid, float((np.median(part.t_ns) - world.t0_ns) / NS)
                    )
                    self.pipelines[sid].pose = self.pose[sid]
                    live = dataclasses.replace(part, t_ns=part.t_ns + offset)
                    self.publishers[sid].on_bearings(self.pipelines[sid].process(live))
            pos = ego.position([t_s])[0]
            state = {
                "x_m": float(pos[0]),
                "y_m": float(pos[1]),
                "heading_deg": float(ego.heading_deg([t_s])[0]) % 360.0,
                "speed_mps": float(ego.speed_mps([t_s])[0]),
                "length_m": length,
                "width_m": width,
                "t_ns": t_end + offset,
            }
            self.vehicle.send(json.dumps(state).encode())
            self.t_s = t_s


def capture_path(demo: DemoResult, sensor_id: str) -> Path:
    return demo.files[f"capture {sensor_id}"]
