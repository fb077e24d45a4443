"""The records that flow between stages, per frame and columnar.

Per-frame dataclasses (:class:`Observation`, :class:`Bearing`) are for the API
edge; the hot path moves :class:`ObservationBatch` and :class:`BearingBatch`,
whose fields are numpy arrays of equal length.

An observation holds the transmitter's raw MAC address and therefore never
leaves the sensor process. A bearing holds only the keyed hash of it (the
emitter id); the privacy stage is the only way from one to the other.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import DataFormatError

MAC_MASK = (1 << 48) - 1
NO_SEQ = -1
"""Value of ``ObservationBatch.seq`` when the frame carries no sequence number."""


class FrameKind(enum.IntEnum):
    """What kind of frame an observation was measured on."""

    UNKNOWN = 0
    BEACON = 1
    PROBE_REQUEST = 2
    PROBE_RESPONSE = 3
    OTHER_MGMT = 4
    CONTROL = 5
    DATA = 6
    QOS_DATA = 7
    BLE_ADV = 8


class ObsFlag(enum.IntFlag):
    """Per-frame quality flags carried in ``ObservationBatch.flags``."""

    NONE = 0
    RETRY = 0x01
    """802.11 retry bit set: a retransmission of an earlier frame."""
    BAD_FCS = 0x02
    """The receiver reported a failed FCS; addresses may be corrupt."""
    NO_SIGNAL = 0x04
    """The receiver reported no signal value for this frame."""
    SENTINEL_CHAIN = 0x08
    """A chain carried a sentinel (-128 or 0 dBm) and was replaced by NaN."""
    MISSING_CHAIN = 0x10
    """Fewer antennas than the batch's width were reported."""
    PAIRED = 0x20
    """RSSI values come from two receivers paired frame by frame."""
    PHASE_AMBIGUOUS = 0x40
    """Per-chain CSI phase may be off by a multiple of π/2 (Intel 5300 at 2.4 GHz)."""
    PHASE_JUMP = 0x80
    """The inter-chain CSI phase jumped against the previous frame of the same transmitter."""


def mac_to_int(text: str) -> int:
    """Parse ``aa:bb:cc:dd:ee:ff`` (``:``, ``-``, ``.`` or no separator) to a 48-bit int.

    Raises:
        DataFormatError: when the text is not 12 hex digits.
    """
    digits = "".join(ch for ch in text if ch not in ":-. ")
    if len(digits) != 12:
        raise DataFormatError(f"not a MAC address: {text!r}")
    try:
        return int(digits, 16)
    except ValueError as err:
        raise DataFormatError(f"not a MAC address: {text!r}") from err


def int_to_mac(value: int) -> str:
    """Format a 48-bit int as lower-case ``aa:bb:cc:dd:ee:ff``."""
    raw = (int(value) & MAC_MASK).to_bytes(6, "big")
    return ":".join(f"{b:02x}" for b in raw)


@dataclass(frozen=True, slots=True)
class Pose:
    """Where a sensor (or vehicle) is and which way it points."""

    x_m: float
    """East coordinate in the local frame, metres (origin: intersection centre)."""
    y_m: float
    """North coordinate in the local frame, metres."""
    heading_deg: float
    """Compass azimuth of the array boresight (or vehicle heading), degrees clockwise from north."""


@dataclass(frozen=True, slots=True)
class Observation:
    """One frame heard by the sensor, with the signal on each antenna.

    Holds a raw MAC address: it never leaves the sensor process.
    """

    t_ns: int
    """Capture time, UTC nanoseconds."""
    mac: int
    """Transmitter MAC address as a 48-bit integer (raw; sensor-internal)."""
    freq_mhz: int
    """Centre frequency of the channel the frame was heard on, MHz (0 if unknown)."""
    channel: int
    """IEEE channel number (0 if unknown)."""
    rssi_dbm: tuple[float, ...]
    """Signal per antenna, dBm, antenna 0 first; NaN where an antenna reported nothing."""
    seq: int | None = None
    """802.11 sequence number (0–4095), or None."""
    kind: FrameKind = FrameKind.UNKNOWN
    """Frame kind."""
    flags: ObsFlag = ObsFlag.NONE
    """Quality flags."""


@dataclass(slots=True)
class CsiBlock:
    """Channel state information beside an :class:`ObservationBatch` (one row per frame).

    The complex channel of every receive antenna, transmit stream and
    subcarrier, antenna order as wired (a receiver's chain permutation already
    undone). NaN marks an antenna or stream the frame did not carry.
    """

    h: npt.NDArray[np.complex64]
    """Channel, shape (n, n_antennas, n_streams, n_subcarriers), linear amplitude (tool units)."""
    subcarrier: npt.NDArray[np.int16]
    """Subcarrier index of each column (spacing 312.5 kHz, 0 = centre), shape (n_subcarriers,)."""

    def __post_init__(self) -> None:
        self.h = np.asarray(self.h, dtype=np.complex64)
        self.subcarrier = np.asarray(self.subcarrier, dtype=np.int16)
        if self.h.ndim != 4 or self.h.shape[3] != self.subcarrier.shape[0]:
            raise ValueError(
                f"CSI of shape {self.h.shape} does not fit {self.subcarrier.shape[0]} subcarriers"
            )

    def __len__(self) -> int:
        return int(self.h.shape[0])

    def select(self, index: npt.NDArray[Any] | slice) -> CsiBlock:
        """Rows picked by a boolean mask, an index array or a slice."""
        return CsiBlock(self.h[index], self.subcarrier)


_NAN_COLUMNS = [np.full(n, np.nan) for n in range(17)]
for _column in _NAN_COLUMNS:
    _column.flags.writeable = False


def _nan_column(n: int) -> npt.NDArray[np.float64]:
    """A column of ``n`` NaN; shared and read-only for short ones."""
    return _NAN_COLUMNS[n] if n < len(_NAN_COLUMNS) else np.full(n, np.nan)


def _as(arr: Any, dtype: npt.DTypeLike, name: str, n: int | None) -> npt.NDArray[Any]:
    out = np.ascontiguousarray(arr, dtype=dtype)
    if n is not None and out.shape[0] != n:
        raise ValueError(f"column {name!r} has {out.shape[0]} rows, expected {n}")
    return out


@dataclass(slots=True)
class ObservationBatch:
    """Columnar observations: every field is an array with one row per frame.

    ``rssi_dbm`` has shape ``(n, n_antennas)``; NaN marks a missing value.
    """

    t_ns: npt.NDArray[np.int64]
    """Capture time, UTC nanoseconds."""
    mac: npt.NDArray[np.uint64]
    """Raw transmitter MAC as 48-bit integers (sensor-internal)."""
    freq_mhz: npt.NDArray[np.int32]
    """Channel centre frequency, MHz (0 if unknown)."""
    channel: npt.NDArray[np.int16]
    """IEEE channel number (0 if unknown)."""
    rssi_dbm: npt.NDArray[np.float32]
    """Signal per antenna, dBm, shape (n, n_antennas), NaN where missing."""
    seq: npt.NDArray[np.int32] = field(default_factory=lambda: np.empty(0, np.int32))
    """802.11 sequence number, or ``NO_SEQ`` (-1)."""
    kind: npt.NDArray[np.uint8] = field(default_factory=lambda: np.empty(0, np.uint8))
    """:class:`FrameKind` values."""
    flags: npt.NDArray[np.uint16] = field(default_factory=lambda: np.empty(0, np.uint16))
    """:class:`ObsFlag` values."""
    csi: CsiBlock | None = None
    """Per-antenna complex channel of each row (CSI sources only), else None."""

    def __post_init__(self) -> None:
        n = len(self.t_ns)
        self.t_ns = _as(self.t_ns, np.int64, "t_ns", None)
        self.mac = _as(self.mac, np.uint64, "mac", n)
        self.freq_mhz = _as(self.freq_mhz, np.int32, "freq_mhz", n)
        self.channel = _as(self.channel, np.int16, "channel", n)
        rssi = np.asarray(self.rssi_dbm, dtype=np.float32)
        if rssi.ndim == 1:
            rssi = rssi.reshape(n, -1) if n else rssi.reshape(0, 2)
        self.rssi_dbm = _as(rssi, np.float32, "rssi_dbm", n)
        self.seq = (
            np.full(n, NO_SEQ, np.int32)
            if len(self.seq) == 0 and n
            else _as(self.seq, np.int32, "seq", n)
        )
        self.kind = (
            np.zeros(n, np.uint8)
            if len(self.kind) == 0 and n
            else _as(self.kind, np.uint8, "kind", n)
        )
        self.flags = (
            np.zeros(n, np.uint16)
            if len(self.flags) == 0 and n
            else _as(self.flags, np.uint16, "flags", n)
        )
        if self.csi is not None and len(self.csi) != n:
            raise ValueError(f"column 'csi' has {len(self.csi)} rows, expected {n}")

    @classmethod
    def empty(cls, n_antennas: int = 2) -> ObservationBatch:
        """A batch with no rows and ``n_antennas`` RSSI columns."""
        return cls(
            t_ns=np.empty(0, np.int64),
            mac=np.empty(0, np.uint64),
            freq_mhz=np.empty(0, np.int32),
            channel=np.empty(0, np.int16),
            rssi_dbm=np.empty((0, n_antennas), np.float32),
        )

    @classmethod
    def from_observations(
        cls, rows: Sequence[Observation], n_antennas: int = 2
    ) -> ObservationBatch:
        """Build a batch from per-frame records (missing antennas become NaN)."""
        n = len(rows)
        rssi = np.full((n, n_antennas), np.nan, np.float32)
        for i, row in enumerate(rows):
            k = min(n_antennas, len(row.rssi_dbm))
            rssi[i, :k] = row.rssi_dbm[:k]
        return cls(
            t_ns=np.array([r.t_ns for r in rows], np.int64),
            mac=np.array([r.mac for r in rows], np.uint64),
            freq_mhz=np.array([r.freq_mhz for r in rows], np.int32),
            channel=np.array([r.channel for r in rows], np.int16),
            rssi_dbm=rssi,
            seq=np.array([NO_SEQ if r.seq is None else r.seq for r in rows], np.int32),
            kind=np.array([int(r.kind) for r in rows], np.uint8),
            flags=np.array([int(r.flags) for r in rows], np.uint16),
        )

    @staticmethod
    def concat(batches: Sequence[ObservationBatch]) -> ObservationBatch:
        """Concatenate batches with the same antenna count, in order.

        CSI is kept when every batch carries it with the same shape and subcarriers.
        """
        if not batches:
            return ObservationBatch.empty()
        csi = None
        first = batches[0].csi
        if first is not None and all(
            b.csi is not None
            and b.csi.h.shape[1:] == first.h.shape[1:]
            and np.array_equal(b.csi.subcarrier, first.subcarrier)
            for b in batches
        ):
            csi = CsiBlock(
                np.concatenate([b.csi.h for b in batches if b.csi is not None]), first.subcarrier
            )
        return ObservationBatch(
            t_ns=np.concatenate([b.t_ns for b in batches]),
            mac=np.concatenate([b.mac for b in batches]),
            freq_mhz=np.concatenate([b.freq_mhz for b in batches]),
            channel=np.concatenate([b.channel for b in batches]),
            rssi_dbm=np.concatenate([b.rssi_dbm for b in batches]),
            seq=np.concatenate([b.seq for b in batches]),
            kind=np.concatenate([b.kind for b in batches]),
            flags=np.concatenate([b.flags for b in batches]),
            csi=csi,
        )

    @property
    def n_antennas(self) -> int:
        """Number of RSSI columns."""
        return int(self.rssi_dbm.shape[1])

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def select(self, index: npt.NDArray[Any] | slice) -> ObservationBatch:
        """Rows picked by a boolean mask, an index array or a slice: taken as they are,
        without converting or checking each column again; a slice with a step is
        checked (which makes its columns contiguous)."""
        csi = None if self.csi is None else self.csi.select(index)
        return _rows(self, index, csi=csi)

    def row(self, i: int) -> Observation:
        """Row ``i`` as an :class:`Observation`."""
        seq = int(self.seq[i])
        return Observation(
            t_ns=int(self.t_ns[i]),
            mac=int(self.mac[i]),
            freq_mhz=int(self.freq_mhz[i]),
            channel=int(self.channel[i]),
            rssi_dbm=tuple(float(v) for v in self.rssi_dbm[i]),
            seq=None if seq == NO_SEQ else seq,
            kind=FrameKind(int(self.kind[i])),
            flags=ObsFlag(int(self.flags[i])),
        )

    def __iter__(self) -> Iterator[Observation]:
        for i in range(len(self)):
            yield self.row(i)


def emitter_hex(emitter: int) -> str:
    """The 16-hex-digit text form of a 64-bit emitter id."""
    return f"{int(emitter) & 0xFFFF_FFFF_FFFF_FFFF:016x}"


@dataclass(frozen=True, slots=True)
class Bearing:
    """One direction-finding result for one frame, safe to share.

    Carries the keyed hash of the transmitter's MAC, never the MAC itself.
    """

    t_ns: int
    """Capture time, UTC nanoseconds."""
    sensor_id: str
    """Id of the sensor that measured it."""
    azimuth_deg: float
    """Compass azimuth of the emitter from the sensor, degrees clockwise from north, [0, 360)."""
    sigma_deg: float
    """One-sigma angle error, degrees, from SNR, calibration slope and RSSI quantisation."""
    snr_db: float
    """Signal-to-noise ratio of the stronger antenna, dB."""
    channel: int
    """IEEE channel number the frame was heard on."""
    emitter: str
    """Emitter id: 16 hex digits of the keyed hash of the MAC for the current nonce epoch."""
    relative_deg: float = math.nan
    """Angle from the array boresight, degrees clockwise (diagnostic)."""


@dataclass(slots=True)
class BearingBatch:
    """Columnar bearings from one sensor; ``emitter`` holds 64-bit hashed ids."""

    sensor_id: str
    """Id of the sensor that measured these bearings."""
    t_ns: npt.NDArray[np.int64]
    """Capture time, UTC nanoseconds."""
    azimuth_deg: npt.NDArray[np.float64]
    """Compass azimuth, degrees clockwise from north, [0, 360)."""
    sigma_deg: npt.NDArray[np.float64]
    """One-sigma angle error, degrees."""
    snr_db: npt.NDArray[np.float64]
    """SNR of the stronger antenna, dB."""
    channel: npt.NDArray[np.int16]
    """IEEE channel number."""
    emitter: npt.NDArray[np.uint64]
    """Keyed hash of the MAC (64 bits) for the epoch of ``t_ns``."""
    relative_deg: npt.NDArray[np.float64] = field(default_factory=lambda: np.empty(0))
    """Angle from the array boresight, degrees clockwise (diagnostic)."""

    def __post_init__(self) -> None:
        n = len(self.t_ns)
        self.t_ns = _as(self.t_ns, np.int64, "t_ns", None)
        self.azimuth_deg = _as(self.azimuth_deg, np.float64, "azimuth_deg", n)
        self.sigma_deg = _as(self.sigma_deg, np.float64, "sigma_deg", n)
        self.snr_db = _as(self.snr_db, np.float64, "snr_db", n)
        self.channel = _as(self.channel, np.int16, "channel", n)
        self.emitter = _as(self.emitter, np.uint64, "emitter", n)
        if len(self.relative_deg) == 0 and n:
            self.relative_deg = np.full(n, np.nan)
        self.relative_deg = _as(self.relative_deg, np.float64, "relative_deg", n)

    @classmethod
    def from_columns(
        cls,
        sensor_id: str,
        t_ns: npt.NDArray[np.int64],
        azimuth_deg: npt.NDArray[np.float64],
        sigma_deg: npt.NDArray[np.float64],
        snr_db: npt.NDArray[np.float64],
        channel: npt.NDArray[np.int16],
        emitter: npt.NDArray[np.uint64],
    ) -> BearingBatch:
        """A batch of columns that already have the fields' dtypes and one length,
        taken as they are: no conversion, copy or check (for a decoder that built
        them so; the message decoder is one). ``relative_deg`` is NaN, read-only."""
        batch = object.__new__(cls)
        batch.sensor_id = sensor_id
        batch.t_ns = t_ns
        batch.azimuth_deg = azimuth_deg
        batch.sigma_deg = sigma_deg
        batch.snr_db = snr_db
        batch.channel = channel
        batch.emitter = emitter
        batch.relative_deg = _nan_column(len(t_ns))
        return batch

    @classmethod
    def empty(cls, sensor_id: str) -> BearingBatch:
        """A batch with no rows."""
        z = np.empty(0)
        return cls(
            sensor_id, np.empty(0, np.int64), z, z, z, np.empty(0, np.int16), np.empty(0, np.uint64)
        )

    @classmethod
    def concat(cls, sensor_id: str, batches: Sequence[BearingBatch]) -> BearingBatch:
        """The rows of ``batches`` end to end, as bearings of ``sensor_id``.

        Empty batches are passed over; a single non-empty batch of that sensor
        is returned as it is (not copied).
        """
        parts = [b for b in batches if len(b)]
        if not parts:
            return cls.empty(sensor_id)
        if len(parts) == 1 and parts[0].sensor_id == sensor_id:
            return parts[0]
        return cls(
            sensor_id=sensor_id,
            t_ns=np.concatenate([p.t_ns for p in parts]),
            azimuth_deg=np.concatenate([p.azimuth_deg for p in parts]),
            sigma_deg=np.concatenate([p.sigma_deg for p in parts]),
            snr_db=np.concatenate([p.snr_db for p in parts]),
            channel=np.concatenate([p.channel for p in parts]),
            emitter=np.concatenate([p.emitter for p in parts]),
            relative_deg=np.concatenate([p.relative_deg for p in parts]),
        )

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def select(self, index: npt.NDArray[Any] | slice) -> BearingBatch:
        """Rows picked by a boolean mask, an index array or a slice, as
        :meth:`ObservationBatch.select` picks them."""
        return _rows(self, index, sensor_id=self.sensor_id)

    def row(self, i: int) -> Bearing:
        """Row ``i`` as a :class:`Bearing`."""
        return Bearing(
            t_ns=int(self.t_ns[i]),
            sensor_id=self.sensor_id,
            azimuth_deg=float(self.azimuth_deg[i]),
            sigma_deg=float(self.sigma_deg[i]),
            snr_db=float(self.snr_db[i]),
            channel=int(self.channel[i]),
            emitter=emitter_hex(int(self.emitter[i])),
            relative_deg=float(self.relative_deg[i]),
        )

    def __iter__(self) -> Iterator[Bearing]:
        for i in range(len(self)):
            yield self.row(i)


def _json_value(value: Any) -> Any:
    """NaN and ±inf become None (JSON has no such numbers); tuples become lists."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, tuple):
        return [_json_value(v) for v in value]
    return value


_Batch = TypeVar("_Batch", ObservationBatch, BearingBatch)


def _rows(batch: _Batch, index: npt.NDArray[Any] | slice, **other: Any) -> _Batch:
    """The rows ``index`` of ``batch``'s columns (every field not in ``other``), with
    the ``other`` fields as given.

    The columns of a batch already have their dtypes and one length, and rows picked
    from them keep both, so they are taken as they are (no conversion or check per
    column); a slice with a step goes through the constructor's checks, which make
    its columns contiguous.
    """
    picked = {f.name: getattr(batch, f.name)[index] for f in fields(batch) if f.name not in other}
    cls = type(batch)
    if isinstance(index, slice) and index.step not in (None, 1):
        return cls(**picked, **other)
    out = object.__new__(cls)
    for name, value in (picked | other).items():
        setattr(out, name, value)
    return out


@dataclass(frozen=True, slots=True)
class Fix:
    """One emitter position triangulated from associated bearings, with its covariance.

    Carries the emitter id (a keyed hash), never a MAC address.
    """

    t_ns: int
    """Capture time of the newest bearing used, UTC nanoseconds."""
    emitter: str
    """Emitter id: 16 hex digits of the keyed hash of the MAC for the nonce epoch."""
    x_m: float
    """East position in the local frame, metres (NaN when no solution exists)."""
    y_m: float
    """North position in the local frame, metres (NaN when no solution exists)."""
    cov_xx_m2: float
    """Variance of ``x_m``, m² (inf when the geometry is singular)."""
    cov_xy_m2: float
    """Covariance of ``x_m`` and ``y_m``, m²."""
    cov_yy_m2: float
    """Variance of ``y_m``, m²."""
    ok: bool
    """True when the fix can be trusted (the geometry and the bearings passed every check)."""
    status: str
    """Why it can or cannot be trusted: ``ok``, ``too_few_bearings``, ``ill_conditioned``,
    ``behind_sensor``, ``inconsistent`` or ``not_converged``."""
    reason: str
    """Human-readable explanation of ``status`` with its numbers."""
    sensors: tuple[str, ...]
    """Ids of the sensors whose bearings were used."""
    gdop: float
    """Geometric dilution of precision: √(σ_x² + σ_y²) over the RMS of range × bearing sigma."""
    condition: float
    """Condition number of the information matrix (1: circular error ellipse)."""

    @property
    def position(self) -> npt.NDArray[np.float64]:
        """``(x_m, y_m)`` as an array."""
        return np.array([self.x_m, self.y_m])

    @property
    def covariance(self) -> npt.NDArray[np.float64]:
        """2×2 covariance of ``position``, m²."""
        return np.array([[self.cov_xx_m2, self.cov_xy_m2], [self.cov_xy_m2, self.cov_yy_m2]])

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready mapping of every field (non-finite numbers as None)."""
        return {name: _json_value(getattr(self, name)) for name in self.__dataclass_fields__}


@dataclass(frozen=True, slots=True)
class Assessment:
    """The backend's judgement of one emitter against the vehicle at one moment.

    Position and velocity come from the emitter's track (filtered fixes);
    risk numbers are NaN when no vehicle state is known.
    """

    t_ns: int
    """Time the assessment refers to, UTC nanoseconds."""
    emitter: str
    """Emitter id: 16 hex digits of the keyed hash of the MAC for the nonce epoch."""
    x_m: float
    """Tracked east position at ``t_ns``, metres."""
    y_m: float
    """Tracked north position at ``t_ns``, metres."""
    cov_xx_m2: float
    """Variance of ``x_m``, m²."""
    cov_xy_m2: float
    """Covariance of ``x_m`` and ``y_m``, m²."""
    cov_yy_m2: float
    """Variance of ``y_m``, m²."""
    vx_mps: float
    """Tracked east velocity, m/s."""
    vy_mps: float
    """Tracked north velocity, m/s."""
    age_s: float
    """Seconds since the newest bearing of the latest fix that set the position."""
    sensors: tuple[str, ...]
    """Sensors whose bearings made the latest fix."""
    fix_ok: bool
    """Whether the latest fix was trustworthy."""
    fix_reason: str
    """Explanation of the latest fix's status."""
    p_collision: float
    """Probability that the vehicle's and the emitter's boxes overlap at closest approach."""
    t_closest_s: float
    """Seconds from ``t_ns`` to the closest approach."""
    distance_to_contact_m: float
    """Along-track gap from the vehicle's front to the emitter's box, metres (inf: behind)."""
    impact_speed_mps: float
    """Speed at contact if the vehicle brakes now, m/s (0: it stops in time)."""
    fatality_risk: float
    """Rosen's pedestrian fatality probability at ``impact_speed_mps``."""
    risk: float
    """``p_collision · fatality_risk``."""
    advisory: str
    """``brake``, ``caution``, ``clear``, or ``none`` when no vehicle state is known."""
    reasons: tuple[str, ...]
    """Why the advisory is what it is, with numbers."""
    link_alarm: bool
    """Whether the link's latency watch was alarmed."""

    @property
    def covariance(self) -> npt.NDArray[np.float64]:
        """2×2 position covariance, m²."""
        return np.array([[self.cov_xx_m2, self.cov_xy_m2], [self.cov_xy_m2, self.cov_yy_m2]])

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready mapping of every field (non-finite numbers as None)."""
        return {name: _json_value(getattr(self, name)) for name in self.__dataclass_fields__}
