"""The cue message (type 3): "listen for this emitter on this channel, now".

A roadside unit that has a bearing of an emitter, or the backend that has a
fix of it, tells the vehicles whose sensors could hear it which channel the
emitter was heard on; their scan schedulers (``rfsas_hw.sources.schedule``)
dwell there instead of waiting for their hop plan to come round. The emitter
is named only by its keyed hash for the nonce epoch, so a vehicle matches its
own bearing to the cue's by comparing hashes it made with the same nonce.

Byte layout (big-endian, the same envelope as the safety message; documented
field by field in ``docs/protocol.md``)::

    off   size  field
    0     2     magic "RF"
    2     1     version = 1
    3     1     type = 3 (cue)
    4     1     flags, reserved, 0
    5     1     L = sender id length, 1..32
    6     L     sender id, ASCII [A-Za-z0-9._-]
    6+L   8     generation time, UTC µs, int64
    14+L  4     sequence number, uint32
    18+L  8     nonce epoch, uint64
    26+L  8     emitter id (keyed MAC hash in that epoch), uint64
    34+L  8     observation time (the bearing's or the fix's), UTC µs, int64
    42+L  8     valid until, UTC µs, int64 (> observation time)
    50+L  2     channel number, uint16
    52+L  1     band: 1 = 2.4 GHz, 2 = 5 GHz, 3 = 6 GHz, 4 = BLE
    53+L  1     PHY: 0 = unknown, 1 = 802.11 legacy (DSSS/OFDM), 2 = HT, 3 = VHT,
                4 = HE, 5 = BLE 1M, 6 = BLE 2M, 7 = BLE coded
    54+L  1     kind: 1 = bearing (x, y = the cueing sensor's position; a = compass
                azimuth, degrees [0, 360); b = its sigma, degrees > 0; c = 0);
                2 = fix (x, y = the emitter's estimated position; a, b, c = its
                covariance xx, xy, yy, m², positive definite)
    55+L  1     reserved, 0
    56+L  4     risk, [0, 1], float32 (the scheduler's priority)
    60+L  4     x, east, metres, float32
    64+L  4     y, north, metres, float32
    68+L  4     a, float32 (see kind)
    72+L  4     b, float32
    76+L  4     c, float32
    80+L  64    ECDSA P-256 signature over every byte before it: r ‖ s
    144+L 8     version 2 only: pre-authentication tag (:mod:`rfsas_hw.link.preauth`)

The length is ``144 + L`` (version 1) or ``152 + L`` (version 2, the version
byte 2 and the tag after the signature, as for the safety message). Checks
follow the safety message's: cheap structural ones first (:func:`peek_cue`,
which also reads the header's times and epoch), the tag, then the signature,
values only after it.
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass

from rfsas_hw.errors import LinkError
from rfsas_hw.link.message import (
    PREAUTH_BYTES,
    SIGNATURE_BYTES,
    VERSION,
    VERSION_PREAUTH,
    MessageFormatError,
    check_sender_id,
    pack_prefix,
    peek_prefix,
)
from rfsas_hw.link.preauth import sign_datagram
from rfsas_hw.link.signing import Signer

TYPE_CUE = 3

_PREFIX = struct.Struct(">2sBBBB")
_BODY = struct.Struct(">qIQQqqHBBBBffffff")
_HEAD = struct.Struct(">qIQ")
"""The body's first fields: generation time, sequence number, nonce epoch."""
CUE_FIXED_BYTES = _PREFIX.size + _BODY.size + SIGNATURE_BYTES
"""Bytes of a cue besides the sender id."""
_INT64_MAX = (1 << 63) - 1


class Band(enum.IntEnum):
    """Radio band of the cued channel."""

    WIFI_2G4 = 1
    WIFI_5G = 2
    WIFI_6G = 3
    BLE = 4


class Phy(enum.IntEnum):
    """Physical layer the emitter was heard with (0 when the sensor cannot tell)."""

    UNKNOWN = 0
    LEGACY = 1
    HT = 2
    VHT = 3
    HE = 4
    BLE_1M = 5
    BLE_2M = 6
    BLE_CODED = 7


class CueKind(enum.IntEnum):
    """What the cue's geometry fields carry."""

    BEARING = 1
    FIX = 2


@dataclass(frozen=True, slots=True)
class Cue:
    """One cue: where and when to listen for a hashed emitter.

    For ``kind == BEARING``, ``x_m, y_m`` is the cueing sensor's position and
    ``a, b`` the bearing's compass azimuth and sigma in degrees (``c`` is 0);
    for ``kind == FIX``, ``x_m, y_m`` is the emitter's estimated position and
    ``a, b, c`` its covariance ``xx, xy, yy`` in m².
    """

    sender_id: str
    """Id of the cueing unit (a roadside sensor or the backend)."""
    t_gen_us: int
    """Generation time, UTC microseconds."""
    seq: int
    """Sequence number, uint32."""
    epoch: int
    """Nonce epoch the emitter id was hashed in."""
    emitter: int
    """Keyed hash of the emitter's MAC in ``epoch``, uint64."""
    t_obs_us: int
    """Time of the bearing or fix the cue is based on, UTC microseconds."""
    valid_until_us: int
    """After this (UTC µs) the cue must not be obeyed."""
    channel: int
    """Channel the emitter was heard on."""
    band: Band
    """Band of ``channel``."""
    phy: Phy
    """PHY the emitter was heard with."""
    kind: CueKind
    """Bearing or fix (see the class docstring)."""
    risk: float
    """Risk the emitter poses, 0–1: the scheduler serves higher risk first."""
    x_m: float
    """East, metres (sensor position or fix position, per ``kind``)."""
    y_m: float
    """North, metres."""
    a: float
    """Azimuth (degrees) or covariance xx (m²), per ``kind``."""
    b: float
    """Sigma (degrees) or covariance xy (m²), per ``kind``."""
    c: float = 0.0
    """0, or covariance yy (m²), per ``kind``."""

    @property
    def valid_s(self) -> float:
        """Length of the validity window after the observation, seconds."""
        return (self.valid_until_us - self.t_obs_us) / 1e6


def _problem(cue: Cue) -> str | None:
    """What is wrong with the values of ``cue``, or None."""
    floats = (cue.risk, cue.x_m, cue.y_m, cue.a, cue.b, cue.c)
    if not all(math.isfinite(v) for v in floats):
        return "risk, position and geometry must be finite"
    if not 0.0 <= cue.risk <= 1.0:
        return f"risk {cue.risk} outside [0, 1]"
    if not 0 <= cue.t_obs_us < cue.valid_until_us <= _INT64_MAX:
        return "validity window must end after the observation time (both after 1970)"
    if cue.t_gen_us < 0:
        return "generation time before 1970"
    if not 0 < cue.channel <= 0x7FFF:
        return f"channel {cue.channel} outside 1..32767"
    if cue.kind is CueKind.BEARING:
        if not (0.0 <= cue.a < 360.0 and cue.b > 0.0 and cue.c == 0.0):
            return "bearing cue needs azimuth in [0, 360), sigma > 0 and c = 0"
    elif not (cue.a > 0.0 and cue.c > 0.0 and cue.a * cue.c - cue.b * cue.b > 0.0):
        return "fix cue needs a positive-definite covariance (xx, xy, yy)"
    return None


def encode_cue_body(cue: Cue, version: int = VERSION) -> bytes:
    """Every byte of ``cue`` that the signature covers (``version`` 1 or 2).

    Raises:
        LinkError: a field is out of range (sender id, sequence, epoch, emitter,
            times, channel, risk, non-finite or inconsistent geometry).
    """
    sender = check_sender_id(cue.sender_id)
    if not 0 <= cue.seq < 1 << 32:
        raise LinkError(f"sequence number {cue.seq} does not fit 32 bits")
    if not 0 <= cue.epoch <= _INT64_MAX:
        raise LinkError(f"epoch {cue.epoch} out of range")
    if not 0 <= cue.emitter < 1 << 64:
        raise LinkError(f"emitter id {cue.emitter} does not fit 64 bits")
    problem = _problem(cue)
    if problem is not None:
        raise LinkError(f"bad cue: {problem}")
    # float32 rounds 359.99999 up to 360.0, which is 0 on the compass
    a = cue.a
    if cue.kind is CueKind.BEARING and struct.unpack(">f", struct.pack(">f", a))[0] >= 360.0:
        a = 0.0
    if version not in (VERSION, VERSION_PREAUTH):
        raise LinkError(f"cue version {version}: 1 or 2")
    head = pack_prefix(version, TYPE_CUE, sender)
    body = _BODY.pack(
        cue.t_gen_us,
        cue.seq,
        cue.epoch,
        cue.emitter,
        cue.t_obs_us,
        cue.valid_until_us,
        cue.channel,
        int(cue.band),
        int(cue.phy),
        int(cue.kind),
        0,
        cue.risk,
        cue.x_m,
        cue.y_m,
        a,
        cue.b,
        cue.c,
    )
    return head + body


def sign_cue(signer: Signer, cue: Cue, preauth_key: bytes | None = None) -> bytes:
    """The signed datagram of ``cue``: version 2 tagged with ``preauth_key`` (the
    sender's pre-authentication key for ``cue.epoch``), else version 1.

    Raises:
        LinkError: the cue does not encode, or names another sender.
    """
    return sign_datagram(
        signer, cue.sender_id, "cue", lambda v: encode_cue_body(cue, v), preauth_key
    )


@dataclass(frozen=True, slots=True)
class PeekedCue:
    """What :func:`peek_cue` learns without any cryptography."""

    version: int
    sender_id: str
    epoch: int
    """Nonce epoch (picks the pre-authentication key)."""
    t_gen_us: int
    """Generation time, UTC µs (judged before any cryptography)."""


def peek_cue(datagram: bytes) -> PeekedCue:
    """Cheap structural checks of a cue datagram.

    Raises:
        MessageFormatError: ``truncated``, ``oversized``, ``bad_magic``,
            ``bad_version``, ``bad_type`` or ``malformed`` (flags, sender id).
    """
    version, kind, sender = peek_prefix(datagram)
    if kind != TYPE_CUE:
        raise MessageFormatError("bad_type", f"message type {kind}, a cue is {TYPE_CUE}")
    size = len(datagram)
    want = CUE_FIXED_BYTES + len(sender) + (PREAUTH_BYTES if version == VERSION_PREAUTH else 0)
    if size < want:
        raise MessageFormatError("truncated", f"{size} bytes, a cue from this sender is {want}")
    if size > want:
        raise MessageFormatError("oversized", f"{size} bytes, a cue from this sender is {want}")
    t_gen_us, _seq, epoch = _HEAD.unpack_from(datagram, _PREFIX.size + len(sender))
    return PeekedCue(version, sender, epoch, t_gen_us)


def decode_cue(datagram: bytes) -> Cue:
    """Parse a cue and check every value (neither tag nor signature is checked here).

    Raises:
        MessageFormatError: structure or values are invalid (``reason`` says which).
    """
    sender = peek_cue(datagram).sender_id
    at = _PREFIX.size + len(sender)
    (
        t_gen_us,
        seq,
        epoch,
        emitter,
        t_obs_us,
        valid_until_us,
        channel,
        band,
        phy,
        kind,
        reserved,
        risk,
        x_m,
        y_m,
        a,
        b,
        c,
    ) = _BODY.unpack_from(datagram, at)
    if reserved != 0:
        raise MessageFormatError("malformed", f"reserved byte {reserved:#04x} set")
    if epoch > _INT64_MAX:
        raise MessageFormatError("malformed", f"epoch {epoch} out of range")
    try:
        cue = Cue(
            sender_id=sender,
            t_gen_us=t_gen_us,
            seq=seq,
            epoch=epoch,
            emitter=emitter,
            t_obs_us=t_obs_us,
            valid_until_us=valid_until_us,
            channel=channel,
            band=Band(band),
            phy=Phy(phy),
            kind=CueKind(kind),
            risk=risk,
            x_m=x_m,
            y_m=y_m,
            a=a,
            b=b,
            c=c,
        )
    except ValueError as err:
        raise MessageFormatError("malformed", f"band, PHY or kind: {err}") from None
    problem = _problem(cue)
    if problem is not None:
        raise MessageFormatError("malformed", problem)
    return cue


def band_of(channel: int, tech: str = "wifi") -> Band:
    """The band of a Wi-Fi or BLE channel number (6 GHz channels are not guessed: 5 GHz).

    Raises:
        LinkError: not a channel number of that technology.
    """
    if tech == "ble":
        if 0 <= channel <= 39:
            return Band.BLE
    elif 1 <= channel <= 14:
        return Band.WIFI_2G4
    elif 32 <= channel <= 177:
        return Band.WIFI_5G
    raise LinkError(f"{channel} is not a {tech} channel")
