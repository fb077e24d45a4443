"""Wi-Fi CSI captures as a source: ``csi:PATH`` (``csi:PATH?freq=2437&format=intel5300``).

Query options: ``freq`` (MHz, for formats that do not record it), ``format``,
``chip`` (nexmon), ``rssi_offset`` (dB added to every RSSI: a relative scale
to dBm).

Reads Intel 5300 ``.dat``, FeitCSI ``.csi`` and ESP32 CSI text itself, Atheros ``.dat``,
PicoScenes ``.csi`` and nexmon_csi pcaps through ``csiread`` (the ``csi``
extra). The format is recognised from the file (override with ``format=``).
Every observation carries the raw MAC (0 where the format has none), RSSI
per antenna (so monopulse still works) and, in ``batch.csi``, the complex
channel per antenna, stream and subcarrier in wired antenna order.

Flags: ``PHASE_AMBIGUOUS`` (5300 at 2.4 GHz), ``SENTINEL_CHAIN`` /
``MISSING_CHAIN`` (−128 or 0 RSSI, dead CSI rows), ``NO_SIGNAL`` (no RSSI
in the format), ``PHASE_JUMP`` (an inter-chain phase step over 60° from the
previous frame of the same transmitter).

``stats.extra`` holds the format, the RSSI unit, what was noticed, and the
inter-chain phase of every antenna pair: ``phase_mean_deg_A_B`` and
``phase_std_deg_A_B`` (circular, over frames, of Σ_k h_A·conj(h_B) on the
first stream) — the numbers ``rfsas replay`` prints.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

import numpy as np

from rfsas_hw.errors import CaptureFormatError, SourceError
from rfsas_hw.records import ObservationBatch
from rfsas_hw.sources.base import Source
from rfsas_hw.sources.csi_frames import (
    CsiCapture,
    PhaseAccumulator,
    flag_phase_jumps,
    mark_missing,
)

FORMATS = ("intel5300", "atheros", "picoscenes", "feitcsi", "nexmon", "esp32")
BATCH_FRAMES = 4096
"""Most frames per batch."""


def detect_format(path: Path) -> str:
    """The CSI tool that wrote ``path``, from its name and first bytes.

    Raises:
        CaptureFormatError: an unrecognised file.
    """
    head = path.read_bytes()[:512]
    suffix = path.suffix.lower()
    if suffix in (".pcap", ".pcapng"):
        return "nexmon"
    if suffix == ".csv" or head.startswith((b"CSI_DATA", b"type,")):
        return "esp32"
    if len(head) >= 3 and head[2] in (0xBB, 0xC1):
        return "intel5300"
    if suffix == ".dat":
        return "atheros"
    if suffix == ".csi":
        if len(head) >= 56:
            length = int.from_bytes(head[0:4], "little")
            nrx, ntx = head[46], head[47]
            nsc = int.from_bytes(head[52:56], "little")
            if 1 <= nrx <= 4 and 1 <= ntx <= 4 and length == 4 * nrx * ntx * nsc:
                return "feitcsi"
        return "picoscenes"
    raise CaptureFormatError(
        f"{path}: not a CSI capture this build reads (.dat Intel 5300/Atheros, .csi "
        "PicoScenes/FeitCSI, .pcap nexmon_csi, .csv ESP32); name the format with ?format=…"
    )


def read_capture(
    path: str | Path, fmt: str | None = None, freq_mhz: int = 0, chip: str | None = None
) -> CsiCapture:
    """Decode a whole CSI file, flags set.

    Raises:
        SourceError: the file does not exist or cannot be read.
        CaptureFormatError: the file is not (or not entirely) a capture of that format.
        MissingDependencyError: the format needs ``csiread`` and it is missing.
    """
    p = Path(path)
    if not p.is_file():
        raise SourceError(f"{path}: no such CSI capture file")
    fmt = fmt or detect_format(p)
    if fmt == "intel5300":
        from rfsas_hw.sources.csi_intel import read_intel5300

        capture = read_intel5300(p, freq_mhz)
    elif fmt == "esp32":
        from rfsas_hw.sources.csi_esp32 import read_esp32

        capture = read_esp32(p, freq_mhz)
    elif fmt == "feitcsi":
        from rfsas_hw.sources.csi_feit import read_feitcsi

        capture = read_feitcsi(p, freq_mhz)
    elif fmt in ("atheros", "picoscenes", "nexmon"):
        from rfsas_hw.sources.csi_csiread import read_isolated

        capture = read_isolated(fmt, p, freq_mhz, chip)
    else:
        raise SourceError(f"{path}: unknown CSI format {fmt!r}; known: {', '.join(FORMATS)}")
    for block in capture.blocks:
        mark_missing(block)
        capture.notes["phase jumps"] += flag_phase_jumps(block)
    return capture


def _parse_arg(arg: str) -> tuple[str, dict[str, str]]:
    path, sep, query = arg.partition("?")
    if not sep or Path(arg).exists():
        return arg, {}
    options: dict[str, str] = {}
    for key, values in parse_qs(query, keep_blank_values=True).items():
        options[key] = values[-1]
    return path, options


class CsiSource(Source[ObservationBatch]):
    """Observations with CSI from a capture file of a Wi-Fi CSI tool.

    Args:
        path: the capture file.
        format: one of :data:`FORMATS`; recognised from the file when None.
        freq_mhz: channel centre frequency for formats that do not record it
            (Intel 5300, FeitCSI); decides the 5300's π/2 flag at 2.4 GHz.
        chip: nexmon chip name when the pcap's chip_version is not known.
        rssi_offset_db: added to every RSSI reading, dB: turns a tool's relative
            scale into dBm (Atheros reports dB above its noise floor, e.g. −95).
        errors, filter: see :class:`~rfsas_hw.sources.base.Source`.

    Raises:
        SourceError: the file is missing, or an option is bad.
        CaptureFormatError: the file cannot be decoded (file and reason named).
    """

    scheme = "csi"

    def __init__(
        self,
        path: str,
        *,
        format: str | None = None,
        freq_mhz: int = 0,
        chip: str | None = None,
        rssi_offset_db: float = 0.0,
        **base: Any,
    ) -> None:
        if not path:
            raise SourceError("csi source needs a path: csi:FILE[?freq=MHz&format=NAME]")
        if format is not None and format not in FORMATS:
            raise SourceError(f"csi:{path}: unknown format {format!r}; known: {', '.join(FORMATS)}")
        if not 0 <= freq_mhz <= 100_000:
            raise SourceError(f"csi:{path}: freq {freq_mhz} MHz is not a channel frequency")
        if not math.isfinite(rssi_offset_db) or abs(rssi_offset_db) > 200:
            raise SourceError(f"csi:{path}: rssi_offset {rssi_offset_db} dB is not plausible")
        self.path = path
        self.capture = read_capture(path, format, freq_mhz, chip)
        if rssi_offset_db:
            for block in self.capture.blocks:
                block.rssi_dbm += np.float32(rssi_offset_db)
            self.capture.rssi_unit = f"{self.capture.rssi_unit} {rssi_offset_db:+g} dB"
        super().__init__(**base)
        self._queue = [b.to_batch() for b in self.capture.blocks]
        self._offset = 0
        phases = PhaseAccumulator()
        for block in self.capture.blocks:
            phases.add(block.h)
        extra = self.stats.extra
        extra["csi_format"] = self.capture.fmt
        extra["rssi_unit"] = self.capture.rssi_unit
        extra["antennas"] = max((b.n_rx for b in self.capture.blocks), default=0)
        for key, count in sorted(self.capture.notes.items()):
            extra[key] = count
        self.phase_stats = phases.result()
        for s in self.phase_stats:
            extra[f"phase_mean_deg_{s.a}_{s.b}"] = round(s.mean_deg, 2)
            extra[f"phase_std_deg_{s.a}_{s.b}"] = round(s.std_deg, 2)
        self._problems_reported = False

    @classmethod
    def from_spec(cls, arg: str, **options: Any) -> Source[Any]:
        """``PATH`` or ``PATH?freq=MHz&format=NAME&chip=NAME&rssi_offset=DB``; keywords win.

        Raises:
            SourceError: an unknown query key or a non-numeric frequency.
        """
        path, query = _parse_arg(arg)
        for key, value in query.items():
            if key == "freq":
                try:
                    options.setdefault("freq_mhz", int(value))
                except ValueError as err:
                    raise SourceError(f"csi:{arg}: freq must be MHz, got {value!r}") from err
            elif key == "rssi_offset":
                try:
                    options.setdefault("rssi_offset_db", float(value))
                except ValueError as err:
                    raise SourceError(f"csi:{arg}: rssi_offset must be dB, got {value!r}") from err
            elif key in ("format", "chip"):
                options.setdefault(key, value)
            else:
                raise SourceError(
                    f"csi:{arg}: unknown option {key!r} (freq, format, chip, rssi_offset)"
                )
        return cls(path, **options)

    def __repr__(self) -> str:
        return f"CsiSource({self.path!r})"

    def _read_raw(self, timeout: float | None) -> ObservationBatch | None:
        if not self._problems_reported:
            self._problems_reported = True
            for reason, error in self.capture.problems:
                self._bad(reason, error)
        if not self._queue:
            self._end()
            return None
        batch = self._queue[0]
        part = batch.select(slice(self._offset, self._offset + BATCH_FRAMES))
        self._offset += BATCH_FRAMES
        if self._offset >= len(batch):
            self._queue.pop(0)
            self._offset = 0
        if not self._queue:
            self._end()
        return part


def capture_frames(path: str | Path, **options: Any) -> ObservationBatch:
    """Every observation of a CSI file in one batch (for offline tools and tests).

    Raises:
        as :class:`CsiSource`.
    """
    source = CsiSource(str(path), errors="skip", **options)
    try:
        batches = list(source)
    finally:
        source.close()
    if not batches:
        return ObservationBatch.empty(int(source.stats.extra.get("antennas", 2)) or 2)
    return ObservationBatch.concat(batches)


__all__ = ["FORMATS", "CsiSource", "capture_frames", "detect_format", "read_capture"]
