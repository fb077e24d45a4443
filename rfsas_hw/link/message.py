"""The safety message: a versioned binary record of one sensor's bearings.

Byte layout (big-endian; documented field by field in ``docs/protocol.md``)::

    off   size  field
    0     2     magic "RF" (0x52 0x46)
    2     1     version = 1
    3     1     type: 1 = safety message, 2 = nonce envelope (privacy.nonces)
    4     1     flags, reserved, 0
    5     1     L = sender id length, 1..32
    6     L     sender id, ASCII [A-Za-z0-9._-]
    6+L   8     generation time, UTC µs, int64
    14+L  4     sequence number, uint32
    18+L  8     nonce epoch, uint64
    26+L  4     sender x, east, metres, float32
    30+L  4     sender y, north, metres, float32
    34+L  4     sender heading, compass degrees, float32
    38+L  1     N = bearing count, 1..255
    39+L  30·N  bearings, each:
                  +0  8  capture time, UTC µs, int64
                  +8  8  emitter id (keyed MAC hash), uint64
                  +16 4  azimuth, compass degrees [0, 360), float32
                  +20 4  sigma, degrees > 0, float32
                  +24 4  SNR, dB, float32
                  +28 2  channel number, uint16
    end-64 64   ECDSA P-256 signature over every byte before it: r ‖ s, 32 bytes each

Version 2 is version 1 with the version byte set to 2 and an 8-byte
pre-authentication tag after the signature: the first 8 bytes of HMAC-SHA256
over every byte before it, keyed with the sender's per-epoch pre-authentication
key (:mod:`rfsas_hw.link.preauth`). A receiver checks the tag before the
signature, so a forgery costs it one HMAC instead of one ECDSA verify. The
signature covers the version byte, so a version-2 message cannot be passed
off as version 1 by stripping its tag.

The length of a valid message follows from L, N and the version alone, so a
receiver can reject a truncated, padded or oversized datagram before any
cryptography.
:func:`peek` does those cheap checks; :func:`decode` parses the rest
(vectorised over the bearings) and checks every value.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from rfsas_hw.errors import LinkError
from rfsas_hw.privacy.nonces import TYPE_NONCE as TYPE_NONCE
from rfsas_hw.records import BearingBatch, Pose

MAGIC = b"RF"
VERSION = 1
"""Version 1: signed, no pre-authentication tag."""
VERSION_PREAUTH = 2
"""Version 2: signed, then tagged with the sender's pre-authentication key."""
VERSIONS = (VERSION, VERSION_PREAUTH)
TYPE_SAFETY = 1
TYPE_ADVISORY = 4
"""The backend's signed assessments (:mod:`rfsas_hw.fleet.advisory`)."""
SIGNATURE_BYTES = 64
PREAUTH_BYTES = 8
"""Length of the truncated HMAC-SHA256 pre-authentication tag of version 2."""
MAX_SENDER_ID = 32
MAX_BEARINGS = 255
MAX_DATAGRAM = 1472
"""Largest datagram the protocol allows: a 1500-byte Ethernet MTU minus IPv4 and UDP headers."""
DEFAULT_DATAGRAM = 1200
"""Default largest datagram a sender builds: fits any path with the IPv6 minimum MTU."""

_PREFIX = struct.Struct(">2sBBBB")
_FIXED = struct.Struct(">qIQfffB")
_GEN_SEQ_EPOCH = struct.Struct(">qIQ")
BEARING_DTYPE = np.dtype(
    [
        ("t_us", ">i8"),
        ("emitter", ">u8"),
        ("azimuth_deg", ">f4"),
        ("sigma_deg", ">f4"),
        ("snr_db", ">f4"),
        ("channel", ">u2"),
    ]
)
BEARING_BYTES = BEARING_DTYPE.itemsize
_BEARING = struct.Struct(">qQfffH")
"""One bearing row on the wire (the layout of :data:`BEARING_DTYPE`)."""
HEADER_BYTES = _PREFIX.size + _FIXED.size
"""Header bytes besides the sender id."""
PREFIX_BYTES = _PREFIX.size
"""Bytes before the sender id; its fixed fields (generation time first) follow it."""
N_BEARINGS_AT = _FIXED.size - 1
"""Offset of the bearing count from the start of the fixed fields, bytes."""
_SENDER_RE = re.compile(rb"[A-Za-z0-9._-]{1,32}")
_SENDER_IDS: dict[bytes, str] = {}
"""Sender ids that passed :data:`_SENDER_RE`, as text: every datagram of a sender
(a flood's included) is checked against the pattern once."""
_SENDER_IDS_KEPT = 4096
_INT64_MAX = (1 << 63) - 1
_MAX_T_US = _INT64_MAX // 1000
"""Latest capture time that still fits int64 nanoseconds."""


class MessageFormatError(LinkError):
    """A datagram is not a well-formed message; ``reason`` says which check failed.

    Reasons: ``truncated``, ``oversized``, ``bad_magic``, ``bad_version``,
    ``bad_type``, ``malformed``.
    """

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass(frozen=True, slots=True)
class SafetyMessage:
    """One signed safety message, decoded.

    ``bearings.t_ns`` carry µs resolution (the wire unit); ``relative_deg`` is
    not sent and decodes as NaN.
    """

    sender_id: str
    """Id of the sending sensor; its enrolled key verifies the signature."""
    pose: Pose
    """Sender position (east/north metres) and boresight heading (compass degrees)."""
    t_gen_us: int
    """Generation time, UTC microseconds."""
    seq: int
    """Sequence number, uint32, one per message per sender."""
    epoch: int
    """Nonce epoch the emitter ids were hashed in."""
    bearings: BearingBatch
    """The bearings; ``bearings.sensor_id == sender_id``."""


class Peeked(NamedTuple):
    """What :func:`peek` learns from a datagram without parsing the bearings (a named
    tuple: every datagram that reaches a receiver makes one, a flood included)."""

    kind: int
    """Message type (``TYPE_SAFETY`` or ``TYPE_NONCE``)."""
    sender_id: str
    """Sender id (empty for a nonce envelope; that type has its own layout)."""
    n_bearings: int
    """Declared bearing count (0 for a nonce envelope)."""
    version: int = VERSION
    """Message format version (1, or 2 with a pre-authentication tag)."""

    @property
    def preauth(self) -> bool:
        """True when the message carries a pre-authentication tag (version 2)."""
        return self.version == VERSION_PREAUTH


def max_bearings(
    sender_id: str, max_datagram: int = DEFAULT_DATAGRAM, version: int = VERSION
) -> int:
    """How many bearings fit one message of at most ``max_datagram`` bytes.

    Raises:
        LinkError: not even one bearing fits.
    """
    tag = PREAUTH_BYTES if version == VERSION_PREAUTH else 0
    room = max_datagram - HEADER_BYTES - len(sender_id) - SIGNATURE_BYTES - tag
    n = min(MAX_BEARINGS, room // BEARING_BYTES)
    if n < 1:
        raise LinkError(f"a datagram of {max_datagram} bytes cannot hold one bearing")
    return n


def check_sender_id(sender_id: str) -> bytes:
    """The wire form of a sender id.

    Raises:
        LinkError: the id is empty, longer than 32 characters or not [A-Za-z0-9._-].
    """
    raw = sender_id.encode("ascii", "replace")
    if not _SENDER_RE.fullmatch(raw):
        raise LinkError(
            f"sender id {sender_id!r} must be 1-{MAX_SENDER_ID} characters of A-Z a-z 0-9 . _ -"
        )
    return raw


Row = tuple[int, int, float, float, float, int]
"""One bearing as the wire holds it: capture time (UTC µs), emitter id, azimuth,
sigma, SNR (float32 values) and channel number."""


def wire_rows(bearings: BearingBatch) -> list[Row]:
    """The rows of ``bearings`` as the wire holds them, not checked (:func:`row_ok`):
    capture times in whole µs, the float columns rounded to float32 (an azimuth
    below 360 that rounds up to 360.0 becomes 0, the same direction on the compass).

    struct, not numpy, packs and checks the rows of one message (a few dozen at
    most): for those a dozen numpy calls cost more than the rows.
    """
    az = bearings.azimuth_deg
    return [
        (t_ns // 1000, emitter, a32 if a32 < 360.0 or not a < 360.0 else 0.0, sigma, snr, ch)
        for t_ns, emitter, a, a32, sigma, snr, ch in zip(
            bearings.t_ns.tolist(),
            bearings.emitter.tolist(),
            az.tolist(),
            az.astype(np.float32).tolist(),
            bearings.sigma_deg.astype(np.float32).tolist(),
            bearings.snr_db.astype(np.float32).tolist(),
            bearings.channel.tolist(),
            strict=True,
        )
    ]


def row_ok(row: Row) -> bool:
    """True when every value of a wire row is in its range: azimuth in [0, 360),
    sigma finite and positive, SNR finite, capture time in 1970–2262, channel
    0–32767 (comparisons with NaN are false, so NaN fails each)."""
    t_us, _, az, sigma, snr, channel = row
    return (
        0.0 <= az < 360.0
        and 0.0 < sigma < math.inf
        and -math.inf < snr < math.inf
        and 0 <= t_us <= _MAX_T_US
        and 0 <= channel <= 0x7FFF
    )


def encode_body(msg: SafetyMessage, version: int = VERSION) -> bytes:
    """Every byte of ``msg`` that the signature covers (the datagram minus the signature
    and, in version 2, the tag).

    Raises:
        LinkError: a field is out of range (sender id, bearing count, non-finite
            or out-of-range values, sequence or epoch overflow).
    """
    rows = wire_rows(msg.bearings)
    problem = _bad_rows(rows)
    if problem is not None:
        raise LinkError(f"bad bearing: {problem}")
    return encode_rows(msg.sender_id, msg.pose, msg.t_gen_us, msg.seq, msg.epoch, rows, version)


def encode_rows(
    sender_id: str,
    pose: Pose,
    t_gen_us: int,
    seq: int,
    epoch: int,
    rows: Sequence[Row],
    version: int = VERSION,
) -> bytes:
    """:func:`encode_body` of a message whose bearings are already wire rows that passed
    :func:`row_ok` (a publisher that drops bad rows made them so; they are not checked
    again). The fields are :class:`SafetyMessage`'s.

    Raises:
        LinkError: a header field is out of range (version, sender id, bearing count,
            sequence number, epoch, a pose that is not finite).
    """
    if version not in VERSIONS:
        raise LinkError(f"message version {version} is not one of {VERSIONS}")
    sender = check_sender_id(sender_id)
    n = len(rows)
    if not 1 <= n <= MAX_BEARINGS:
        raise LinkError(f"a message carries 1-{MAX_BEARINGS} bearings, got {n}")
    if not 0 <= seq < 1 << 32:
        raise LinkError(f"sequence number {seq} does not fit 32 bits")
    if not 0 <= epoch < 1 << 64:
        raise LinkError(f"epoch {epoch} does not fit 64 bits")
    xyh = (pose.x_m, pose.y_m, pose.heading_deg)
    if not all(math.isfinite(v) for v in xyh):
        raise LinkError(f"sender pose must be finite, got {pose}")
    head = pack_prefix(version, TYPE_SAFETY, sender)
    fixed = _FIXED.pack(t_gen_us, seq, epoch, *xyh, n)
    return b"".join([head, fixed, *(_BEARING.pack(*row) for row in rows)])


def pack_prefix(version: int, kind: int, sender: bytes) -> bytes:
    """The common 6-byte header and the sender id: magic, version, type, flags 0, L, id.

    Every signed message type (safety, cue, advisory) starts with it.
    """
    return _PREFIX.pack(MAGIC, version, kind, 0, len(sender)) + sender


def peek_prefix(datagram: bytes, max_datagram: int = MAX_DATAGRAM) -> tuple[int, int, str]:
    """Cheap checks of the common header of a signed message: size, magic, version,
    flags, sender id. Returns (version, type, sender id); the type-specific length
    and fields are the caller's to check.

    Raises:
        MessageFormatError: with ``reason`` naming the failed check.
    """
    size, version, kind, flags, sender_len = _unpack_prefix(datagram, max_datagram)
    _check_version(version)
    _check_flags(flags)
    end = _PREFIX.size + sender_len
    if size < end:
        raise MessageFormatError("truncated", f"{size} bytes, sender id needs {end}")
    sender = bytes(datagram[_PREFIX.size : end])
    _check_sender(sender)
    return version, kind, sender.decode("ascii")


def _unpack_prefix(datagram: bytes, max_datagram: int) -> tuple[int, int, int, int, int]:
    """(size, version, type, flags, sender id length) of a datagram whose size and
    magic pass.

    Raises:
        MessageFormatError: ``oversized``, ``truncated`` or ``bad_magic``.
    """
    size = len(datagram)
    if size > max_datagram:
        raise MessageFormatError("oversized", f"{size} bytes > {max_datagram}")
    if size < _PREFIX.size:
        raise MessageFormatError("truncated", f"{size} bytes, header needs {_PREFIX.size}")
    magic, version, kind, flags, sender_len = _PREFIX.unpack_from(datagram)
    if magic != MAGIC:
        raise MessageFormatError("bad_magic", f"starts with {bytes(datagram[:2])!r}")
    return size, version, kind, flags, sender_len


def _check_version(version: int) -> None:
    if version not in VERSIONS:
        raise MessageFormatError(
            "bad_version", f"version {version}, this reader speaks {', '.join(map(str, VERSIONS))}"
        )


def _check_flags(flags: int) -> None:
    if flags != 0:
        raise MessageFormatError("malformed", f"reserved flags {flags:#04x} set")


def _check_sender(sender: bytes) -> None:
    if not _SENDER_RE.fullmatch(sender):
        raise MessageFormatError("malformed", f"sender id {sender!r} is not [A-Za-z0-9._-]{{1,32}}")


def _bad_rows(rows: Sequence[Row]) -> str | None:
    """What is wrong with bearing rows (t_us, emitter, az, sigma, snr, channel), or
    None. One pass when all is well."""
    for row in rows:
        if not row_ok(row):
            break
    else:
        return None
    if not all(0.0 <= r[2] < 360.0 for r in rows):
        return "azimuth outside [0, 360) degrees"
    if not all(0.0 < r[3] < math.inf for r in rows):
        return "sigma must be finite and positive"
    if not all(-math.inf < r[4] < math.inf for r in rows):
        return "SNR must be finite"
    if not all(r[0] >= 0 for r in rows):
        return "capture time before 1970"
    if not all(r[0] <= _MAX_T_US for r in rows):
        return "capture time out of range"
    if not all(r[5] >= 0 for r in rows):
        return "channel numbers must not be negative"
    return "channel number above 32767"


def peek(datagram: bytes, max_datagram: int = MAX_DATAGRAM) -> Peeked:
    """Cheap structural checks: size, magic, version, type, sender id, exact length.

    Raises:
        MessageFormatError: with ``reason`` naming the failed check.
    """
    size, version, kind, flags, sender_len = _unpack_prefix(datagram, max_datagram)
    if kind == TYPE_NONCE and version == VERSION:
        return Peeked(TYPE_NONCE, "", 0)
    _check_version(version)
    if kind == TYPE_NONCE:
        return Peeked(TYPE_NONCE, "", 0)
    if kind != TYPE_SAFETY:
        raise MessageFormatError("bad_type", f"message type {kind}")
    _check_flags(flags)
    fixed_at = _PREFIX.size + sender_len
    if size < fixed_at + _FIXED.size:
        raise MessageFormatError("truncated", f"{size} bytes, header needs {fixed_at + 33}")
    raw = bytes(datagram[_PREFIX.size : fixed_at])
    sender = _SENDER_IDS.get(raw)
    if sender is None:
        _check_sender(raw)
        if len(_SENDER_IDS) >= _SENDER_IDS_KEPT:
            _SENDER_IDS.clear()
        sender = _SENDER_IDS[raw] = raw.decode("ascii")
    n = datagram[fixed_at + _FIXED.size - 1]
    if n == 0:
        raise MessageFormatError("malformed", "no bearings")
    want = fixed_at + _FIXED.size + n * BEARING_BYTES + SIGNATURE_BYTES
    if version == VERSION_PREAUTH:
        want += PREAUTH_BYTES
    if size < want:
        raise MessageFormatError("truncated", f"{size} bytes, {n} bearings need {want}")
    if size > want:
        raise MessageFormatError("oversized", f"{size} bytes, {n} bearings need {want}")
    return Peeked(TYPE_SAFETY, sender, n, version)


def decode(datagram: bytes, max_datagram: int = MAX_DATAGRAM) -> SafetyMessage:
    """Parse a safety message and check every value (the signature is not checked here).

    Raises:
        MessageFormatError: structure or values are invalid (``reason`` says which).
    """
    head = peek(datagram, max_datagram)
    if head.kind != TYPE_SAFETY:
        raise MessageFormatError("bad_type", "a nonce envelope, not a safety message")
    return decode_peeked(datagram, head)


def decode_peeked(datagram: bytes, head: Peeked) -> SafetyMessage:
    """:func:`decode` for a datagram :func:`peek` has already passed as a safety message.

    Raises:
        MessageFormatError: a value is invalid (reason ``malformed``).
    """
    fixed_at = _PREFIX.size + len(head.sender_id)
    t_gen_us, seq, epoch, x_m, y_m, heading_deg, _ = _FIXED.unpack_from(datagram, fixed_at)
    if not (math.isfinite(x_m) and math.isfinite(y_m) and 0.0 <= heading_deg < 360.0):
        raise MessageFormatError("malformed", "sender pose not finite or heading outside [0, 360)")
    if t_gen_us < 0:
        raise MessageFormatError("malformed", "generation time before 1970")
    if epoch > _INT64_MAX:
        raise MessageFormatError("malformed", f"epoch {epoch} out of range")
    at = fixed_at + _FIXED.size
    # struct, not numpy: a message holds at most a few dozen rows (one datagram), and
    # for those a dozen numpy calls cost more than the rows (bench/bench_link.py)
    rows = list(_BEARING.iter_unpack(datagram[at : at + head.n_bearings * BEARING_BYTES]))
    problem = _bad_rows(rows)
    if problem is not None:
        raise MessageFormatError("malformed", problem)
    t_us, emitter, az, sigma, snr, channel = zip(*rows, strict=True)
    bearings = BearingBatch.from_columns(
        head.sender_id,
        np.array(t_us, np.int64) * 1000,
        np.array(az, np.float64),
        np.array(sigma, np.float64),
        np.array(snr, np.float64),
        np.array(channel, np.int16),
        np.array(emitter, np.uint64),
    )
    return SafetyMessage(
        sender_id=head.sender_id,
        pose=Pose(x_m, y_m, heading_deg),
        t_gen_us=t_gen_us,
        seq=seq,
        epoch=epoch,
        bearings=bearings,
    )


def signed_part(datagram: bytes) -> tuple[bytes, bytes]:
    """Split a signed datagram into (signed bytes, 64-byte signature); a version-2
    datagram's pre-authentication tag is left out of both."""
    if len(datagram) > 2 and datagram[2] == VERSION_PREAUTH:
        end = len(datagram) - PREAUTH_BYTES
        return datagram[: end - SIGNATURE_BYTES], datagram[end - SIGNATURE_BYTES : end]
    return datagram[:-SIGNATURE_BYTES], datagram[-SIGNATURE_BYTES:]


def preauth_part(datagram: bytes) -> tuple[bytes, bytes]:
    """Split a version-2 datagram into (tagged bytes, 8-byte pre-authentication tag)."""
    return datagram[:-PREAUTH_BYTES], datagram[-PREAUTH_BYTES:]


def header_epoch(datagram: bytes, head: Peeked) -> tuple[int, int, int]:
    """(generation time µs, sequence number, epoch) of a peeked safety message, read
    without checking anything else: for cheap decisions before the signature."""
    t_gen_us, seq, epoch = _GEN_SEQ_EPOCH.unpack_from(datagram, _PREFIX.size + len(head.sender_id))
    return int(t_gen_us), int(seq), int(epoch)
