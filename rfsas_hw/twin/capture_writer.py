"""Capture files from the twin: radiotap pcap/pcapng per receiver card, and ground truth.

Files are written with scapy's raw writers (``RawPcapWriter`` with
nanosecond timestamps, ``RawPcapNgWriter``), link type 127 (radiotap). A
two-chain card gets one file with both chains in mac80211-style namespaces;
two single-chain cards get one file each. Everything is a function of the
scenario and its seed: the same scenario gives byte-identical files.

The ground truth (``truth.jsonl``) holds one JSON object per line: a
``scenario`` header, one ``emitter`` line per emitter (id, technology, what
carries it; never the MAC), ``track`` samples of every mover, and
``sensor_pose`` samples of every sensor.
"""

from __future__ import annotations

import decimal
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
from scapy.utils import RawPcapNgWriter, RawPcapWriter

from rfsas_hw.errors import DataFormatError, SimulationError
from rfsas_hw.records import mac_to_int
from rfsas_hw.twin.board_stream import board_stream
from rfsas_hw.twin.frames import RadiotapInfo, dot11_frame, radiotap_header, rate_for, with_fcs
from rfsas_hw.twin.world import CHAIN_PRESENT, CHAIN_SENTINEL, Receptions, World

LINKTYPE_RADIOTAP = 127
CaptureFormat = Literal["pcap", "pcapng"]
TRUTH_FILE = "truth.jsonl"
TRUTH_RATE_HZ = 10.0


def card_file_names(sensor_id: str, n_cards: int, fmt: CaptureFormat = "pcap") -> list[str]:
    """Capture file names of a sensor: ``ID.pcap``, or ``ID-card0.pcap`` and ``ID-card1.pcap``."""
    if n_cards == 1:
        return [f"{sensor_id}.{fmt}"]
    return [f"{sensor_id}-card{c}.{fmt}" for c in range(n_cards)]


def _int_dbm(value: float, sentinel: int) -> int:
    return int(np.clip(np.round(value), -128, 127)) if np.isfinite(value) else sentinel


def card_records(world: World, rec: Receptions, card: int) -> Iterator[tuple[int, bytes]]:
    """(capture time UTC ns, radiotap + 802.11 bytes) of every frame card ``card`` captured."""
    spec = world.scenario.spec
    s = world.scenario.sensor(rec.sensor_id)
    sentinel = s.driver.missing_chain_dbm
    emitters = spec.emitters
    peers = [
        mac_to_int(next((t.peer_mac for t in e.traffic if t.model == "data-bursts"), "0" * 12))
        for e in emitters
    ]
    ssids = [next((t.ssid for t in e.traffic if t.model == "beacon"), "") for e in emitters]
    order = np.argsort(rec.capture_ns[:, card], kind="stable")
    for i in order:
        if not rec.heard[i, card]:
            continue
        e = int(rec.emitter[i])
        kind = int(rec.kind[i])
        t_ns = int(rec.t_ns[i])
        if rec.n_cards == 1:
            chains = [
                (_int_dbm(rec.chain_dbm[i, k], sentinel), k)
                for k in range(2)
                if rec.chain_state[i, k] in (CHAIN_PRESENT, CHAIN_SENTINEL)
            ]
            combined = rec.combined_dbm[i]
        else:
            chains = [(_int_dbm(rec.chain_dbm[i, card], sentinel), 0)]
            combined = rec.chain_dbm[i, card]
        info = RadiotapInfo(
            tsft_us=int(rec.tsft_us[i, card]),
            freq_mhz=int(rec.freq_mhz[i]),
            rate_500kbps=rate_for(kind, int(rec.freq_mhz[i])),
            combined_dbm=_int_dbm(combined, sentinel) if np.isfinite(combined) else None,
            chains=chains,
        )
        frame = dot11_frame(
            kind,
            int(rec.mac[i]),
            int(rec.seq[i]),
            int(rec.channel[i]),
            t_ns,
            peer=peers[e],
            ssid=ssids[e],
            beacon_tsf_us=(t_ns // 1000) % (1 << 40) + 7_000_000 * (e + 1),
        )
        yield int(rec.capture_ns[i, card]), radiotap_header(info) + with_fcs(frame)


def write_capture(path: Path, records: Iterator[tuple[int, bytes]], fmt: CaptureFormat) -> int:
    """Write radiotap records to ``path`` as pcap (ns timestamps) or pcapng; returns the count.

    Raises:
        SimulationError: the file cannot be written.
    """
    count = 0
    try:
        if fmt == "pcap":
            pcap = RawPcapWriter(str(path), linktype=LINKTYPE_RADIOTAP, nano=True, endianness="<")
            with pcap:
                pcap._write_header(None)
                for t_ns, data in records:
                    pcap.write_packet(data, sec=t_ns // 1_000_000_000, usec=t_ns % 1_000_000_000)
                    count += 1
        else:
            ng = RawPcapNgWriter(str(path))
            ng.linktype = LINKTYPE_RADIOTAP
            with ng:
                ng._write_header(None)
                for t_ns, data in records:
                    # a Decimal keeps the microsecond exact where a float would round
                    sec = decimal.Decimal(t_ns) / decimal.Decimal(1_000_000_000)
                    ng.write_packet(data, sec=sec)  # type: ignore[arg-type]
                    count += 1
    except OSError as err:
        raise SimulationError(f"{path}: cannot write capture: {err.strerror or err}") from err
    return count


@dataclass
class CaptureSet:
    """What :func:`write_captures` wrote."""

    directory: Path
    """Output directory."""
    files: dict[str, list[Path]] = field(default_factory=dict)
    """Capture files per sensor id, in card order."""
    frames: dict[str, list[int]] = field(default_factory=dict)
    """Frames written per sensor id, per card."""
    truth: Path | None = None
    """The ground-truth JSONL file."""
    board_streams: dict[str, Path] = field(default_factory=dict)
    """Serial-board byte streams per sensor id."""
    board_boot_utc_ns: dict[str, int] = field(default_factory=dict)
    """UTC time of board time 0 of each serial-board stream, ns."""


def write_captures(world: World, directory: str | Path, fmt: CaptureFormat = "pcap") -> CaptureSet:
    """Write every radiotap sensor's captures and the ground truth into ``directory``.

    Serial-board sensors get ``ID.board.bin``: the board-protocol byte stream
    (:mod:`rfsas_hw.twin.board_stream`).

    Raises:
        SimulationError: the directory or a file cannot be written.
    """
    out = Path(directory)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SimulationError(f"{out}: cannot create directory: {err.strerror or err}") from err
    result = CaptureSet(directory=out)
    for s in world.scenario.spec.sensors:
        if s.receiver == "serial-board":
            data, info = board_stream(world, s.id)
            path = out / f"{s.id}.board.bin"
            try:
                path.write_bytes(data)
            except OSError as err:
                raise SimulationError(f"{path}: cannot write: {err.strerror or err}") from err
            result.board_streams[s.id] = path
            result.board_boot_utc_ns[s.id] = info.boot_utc_ns
            result.frames[s.id] = [info.measurements]
            continue
        rec = world.receptions(s.id)
        names = card_file_names(s.id, rec.n_cards, fmt)
        result.files[s.id] = []
        result.frames[s.id] = []
        for card, name in enumerate(names):
            path = out / name
            result.frames[s.id].append(write_capture(path, card_records(world, rec, card), fmt))
            result.files[s.id].append(path)
    result.truth = write_truth(world, out / TRUTH_FILE, result)
    return result


# -- ground truth ------------------------------------------------------------------


def _truth_times(world: World) -> npt.NDArray[np.float64]:
    n = int(np.floor(world.duration_s * TRUTH_RATE_HZ)) + 1
    return np.arange(n) / TRUTH_RATE_HZ


def truth_lines(world: World, captures: CaptureSet | None = None) -> Iterator[dict[str, Any]]:
    """The ground-truth records, in file order."""
    spec = world.scenario.spec
    yield {
        "type": "scenario",
        "name": spec.name,
        "version": spec.version,
        "seed": spec.seed,
        "start_utc": spec.start_utc,
        "t0_ns": world.t0_ns,
        "duration_s": spec.duration_s,
        "detail": world.detail,
        "ego": spec.ego,
    }
    for e in spec.emitters:
        yield {
            "type": "emitter",
            "id": e.id,
            "tech": e.tech,
            "carried_by": e.carried_by,
            "position": list(e.position) if e.position is not None else None,
        }
    t = _truth_times(world)
    t_ns = world.t0_ns + np.round(t * 1e9).astype(np.int64)
    for m in spec.movers:
        track = world.tracks[m.id]
        xy, v, hd = track.position(t), track.velocity(t), track.heading_deg(t)
        length, width = m.size_m()
        for k in range(len(t)):
            yield {
                "type": "track",
                "id": m.id,
                "kind": m.kind,
                "t_ns": int(t_ns[k]),
                "x_m": round(float(xy[k, 0]), 6),
                "y_m": round(float(xy[k, 1]), 6),
                "vx_mps": round(float(v[k, 0]), 6),
                "vy_mps": round(float(v[k, 1]), 6),
                "heading_deg": round(float(hd[k]), 6),
                "length_m": length,
                "width_m": width,
            }
    for s in spec.sensors:
        xy, hd = world.sensor_pose(s, t)
        files = [p.name for p in captures.files.get(s.id, [])] if captures else []
        for k in range(len(t)):
            row: dict[str, Any] = {
                "type": "sensor_pose",
                "id": s.id,
                "t_ns": int(t_ns[k]),
                "x_m": round(float(xy[k, 0]), 6),
                "y_m": round(float(xy[k, 1]), 6),
                "heading_deg": round(float(hd[k]), 6),
            }
            if k == 0:
                row["receiver"] = s.receiver
                row["files"] = files
                if captures and s.id in captures.board_streams:
                    row["files"] = [captures.board_streams[s.id].name]
                    row["board_boot_utc_ns"] = captures.board_boot_utc_ns[s.id]
            yield row


def write_truth(world: World, path: Path, captures: CaptureSet | None = None) -> Path:
    """Write the ground truth as JSONL.

    Raises:
        SimulationError: the file cannot be written.
    """
    try:
        with path.open("w", encoding="utf-8") as f:
            for line in truth_lines(world, captures):
                f.write(json.dumps(line, sort_keys=True) + "\n")
    except OSError as err:
        raise SimulationError(f"{path}: cannot write ground truth: {err.strerror or err}") from err
    return path


@dataclass
class TruthTrack:
    """Samples of one mover (or sensor pose) from a ground-truth file."""

    t_ns: npt.NDArray[np.int64]
    """Sample times, UTC ns."""
    x_m: npt.NDArray[np.float64]
    """East, metres."""
    y_m: npt.NDArray[np.float64]
    """North, metres."""
    heading_deg: npt.NDArray[np.float64]
    """Compass heading, degrees."""
    vx_mps: npt.NDArray[np.float64]
    """East velocity, m/s (zeros for sensor poses)."""
    vy_mps: npt.NDArray[np.float64]
    """North velocity, m/s (zeros for sensor poses)."""

    def position_at(self, t_ns: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Linearly interpolated positions at ``t_ns``, shape (n, 2), metres."""
        t = np.atleast_1d(np.asarray(t_ns, dtype=np.float64))
        tt = self.t_ns.astype(np.float64)
        return np.stack([np.interp(t, tt, self.x_m), np.interp(t, tt, self.y_m)], -1)


@dataclass
class GroundTruth:
    """A parsed ground-truth file."""

    scenario: dict[str, Any]
    """The header line."""
    emitters: dict[str, dict[str, Any]]
    """Emitter lines by id."""
    tracks: dict[str, TruthTrack]
    """Mover tracks by mover id."""
    sensor_poses: dict[str, TruthTrack]
    """Sensor poses by sensor id."""

    def emitter_position(self, emitter_id: str, t_ns: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Where emitter ``emitter_id`` was at ``t_ns``, shape (n, 2), metres.

        Raises:
            DataFormatError: unknown emitter.
        """
        e = self.emitters.get(emitter_id)
        if e is None:
            raise DataFormatError(f"ground truth has no emitter {emitter_id!r}")
        if e.get("carried_by"):
            return self.tracks[e["carried_by"]].position_at(t_ns)
        n = len(np.atleast_1d(np.asarray(t_ns)))
        return np.tile(np.asarray(e["position"], np.float64), (n, 1))


def read_truth(path: str | Path) -> GroundTruth:
    """Parse a ground-truth JSONL file.

    Raises:
        DataFormatError: unreadable file, bad JSON or a record without its fields
            (named with the line number).
    """
    p = Path(path)
    header: dict[str, Any] | None = None
    emitters: dict[str, dict[str, Any]] = {}
    rows: dict[tuple[str, str], list[dict[str, Any]]] = {}
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as err:
        raise DataFormatError(f"{p}: cannot read: {err.strerror or err}") from err
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
            kind = obj["type"]
            if kind == "scenario":
                header = obj
            elif kind == "emitter":
                emitters[str(obj["id"])] = obj
            elif kind in ("track", "sensor_pose"):
                float(obj["x_m"]), float(obj["y_m"]), int(obj["t_ns"])
                rows.setdefault((kind, str(obj["id"])), []).append(obj)
            else:
                raise DataFormatError(f"{p}: line {n}: unknown record type {kind!r}")
        except (ValueError, KeyError, TypeError) as err:
            raise DataFormatError(f"{p}: line {n}: bad ground-truth record: {err}") from err
    if header is None:
        raise DataFormatError(f"{p}: no scenario header line")

    def build(items: list[dict[str, Any]]) -> TruthTrack:
        def col(name: str) -> npt.NDArray[np.float64]:
            return np.array([float(r.get(name, 0.0)) for r in items])

        return TruthTrack(
            t_ns=np.array([int(r["t_ns"]) for r in items], np.int64),
            x_m=col("x_m"),
            y_m=col("y_m"),
            heading_deg=col("heading_deg"),
            vx_mps=col("vx_mps"),
            vy_mps=col("vy_mps"),
        )

    tracks = {i: build(v) for (k, i), v in rows.items() if k == "track"}
    poses = {i: build(v) for (k, i), v in rows.items() if k == "sensor_pose"}
    return GroundTruth(header, emitters, tracks, poses)
