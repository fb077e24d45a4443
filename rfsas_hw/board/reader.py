"""Turn a byte stream into checked frames and messages, counting every loss.

:class:`FrameDecoder` is push-based (``feed(bytes)``) and transport-agnostic;
:class:`FrameReader` pulls from anything with ``read(n)`` (a file, a serial
port, a socket wrapper) and yields ``(raw_bytes, message)``.

Recovery rules (``firmware_protocol/SPEC.md`` §Receiving):

- Frames end at ``0x00``; a bad segment costs only itself. Garbage that ran
  into the next frame without a delimiter is cut off the front of that frame
  (a "resync"), so a frame whose own bytes are intact is never lost.
- Sequence numbers are tracked only from frames whose CRC checked, so
  ``lost`` counts exactly the frames the sender numbered and the receiver
  did not deliver, whatever happened to them (CRC error, unknown type,
  unknown incompatible flag, bytes dropped on the line).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import Any, Literal, Protocol

import numpy as np
import numpy.typing as npt

from rfsas_hw.board.codec import CRC_STARTS, decode_payload
from rfsas_hw.board.columns import is_measurement, records
from rfsas_hw.board.framing import (
    MAX_ENCODED,
    Frame,
    FrameError,
    check_frame,
    cobs_decode,
    recover_suffix,
)
from rfsas_hw.board.messages import CompatFlag, Message, PayloadError
from rfsas_hw.errors import BoardProtocolError

MAX_KEPT_ERRORS = 20
_RESTART = int(CompatFlag.RESTART)


@dataclass
class LinkStats:
    """What a decoder saw on the line. ``lost`` is exact; the others say why."""

    bytes: int = 0
    """Bytes fed in."""
    frames: int = 0
    """Frames that passed every check."""
    crc_errors: int = 0
    """Segments with a plausible header whose CRC did not match."""
    resyncs: int = 0
    """Runs of bytes discarded to find the next frame (bad segments, cut-off garbage)."""
    discarded_bytes: int = 0
    """Non-delimiter bytes that were not part of a delivered frame."""
    unknown_types: int = 0
    """Well-formed frames of a message type this implementation does not know (skipped)."""
    incompatible: int = 0
    """Frames dropped for an unknown incompatible flag."""
    bad_payloads: int = 0
    """Frames whose CRC checked but whose payload did not fit the message layout."""
    truncated: int = 0
    """A frame cut off by the end of the input."""
    sequence_gaps: int = 0
    """Places where the sequence number jumped forward (one per run of lost frames)."""
    lost: int = 0
    """Frames the sender numbered that were never delivered (sum of the gap widths)."""
    restarts: int = 0
    """Sender restarts (RESTART flag, or the sequence number jumped back)."""
    errors: list[str] = field(default_factory=list)
    """The first few error messages, with their byte offsets."""

    def as_dict(self) -> dict[str, Any]:
        """A JSON-friendly copy."""
        return asdict(self)


class Readable(Protocol):
    """Anything with ``read(n)`` (returns b"" at the end or on a timeout)."""

    def read(self, size: int = ..., /) -> bytes: ...


class FrameDecoder:
    """Push bytes in, get checked frames out; counters in :attr:`stats`.

    Args:
        crc_starts: known message types and their CRC start values (default:
            every version-1 type).
    """

    def __init__(self, crc_starts: dict[int, int] | None = None) -> None:
        self.crc_starts = CRC_STARTS if crc_starts is None else crc_starts
        self.stats = LinkStats()
        self._buf = b""
        self._offset = 0  # stream offset of self._buf[0]
        self._expect: int | None = None
        self.new_errors: list[FrameError] = []
        """Errors raised by the last :meth:`feed` (for a raise-on-error policy)."""

    def _note(self, err: FrameError, offset: int) -> None:
        err.offset = offset
        self.new_errors.append(err)
        if len(self.stats.errors) < MAX_KEPT_ERRORS:
            self.stats.errors.append(f"byte {offset}: {err}")

    def _reject(self, err: FrameError, size: int, offset: int) -> None:
        st = self.stats
        st.discarded_bytes += size
        kind = err.kind
        if kind == "crc":
            st.crc_errors += 1
        elif kind == "unknown_type":
            st.unknown_types += 1
        elif kind == "incompatible":
            st.incompatible += 1
        else:
            st.resyncs += 1
        self._note(err, offset)

    def _track(self, seq: int, compat: int) -> None:
        expect = self._expect
        if expect is not None and seq != expect:
            gap = (seq - expect) & 0xFFFF
            if compat & _RESTART or gap >= 0x8000:
                self.stats.restarts += 1
            else:
                self.stats.sequence_gaps += 1
                self.stats.lost += gap
        elif expect is None and compat & _RESTART:
            self.stats.restarts += 1
        self._expect = (seq + 1) & 0xFFFF

    def _segment(self, seg: bytes, pos: int) -> tuple[bytes, Frame] | None:
        """Decode one non-empty segment at stream offset ``pos``, counting what fails."""
        st = self.stats
        n = len(seg)
        try:
            if n > MAX_ENCODED:
                raise FrameError("length", f"segment of {n} bytes exceeds {MAX_ENCODED}")
            frame = check_frame(cobs_decode(seg), self.crc_starts)
        except FrameError as err:
            found = recover_suffix(seg, self.crc_starts)
            if found is None:
                self._reject(err, n, pos)
                return None
            skip, frame = found
            st.resyncs += 1
            st.discarded_bytes += skip
            self._note(FrameError("garbage", f"{skip} bytes of garbage before a frame"), pos)
            seg = seg[skip:]
        st.frames += 1
        return seg + b"\x00", frame

    def _keep_tail(self, tail: bytes, pos: int) -> None:
        if len(tail) > MAX_ENCODED:
            # no delimiter for longer than any frame: keep only what could
            # still be the start of one
            cut = len(tail) - MAX_ENCODED
            self.stats.resyncs += 1
            self.stats.discarded_bytes += cut
            self._note(FrameError("length", f"{cut} bytes without a delimiter"), pos)
            tail = tail[cut:]
            pos += cut
        self._buf = tail
        self._offset = pos

    def feed(self, data: bytes) -> list[tuple[bytes, Frame]]:
        """Decode every complete frame in ``data`` (plus what was buffered).

        Returns ``(raw, frame)`` pairs, ``raw`` being the frame's wire bytes
        including the delimiter. Bad segments are counted, never raised.
        """
        return [(raw, frame) for raw, frame, _ in self._feed(data)]

    def _feed(self, data: bytes) -> list[tuple[bytes, Frame, int]]:
        """:meth:`feed`, with the stream offset of each frame's segment."""
        self.new_errors = []
        self.stats.bytes += len(data)
        buf = self._buf + data if self._buf else data
        parts = buf.split(b"\x00")
        tail = parts.pop()
        pos = self._offset
        out: list[tuple[bytes, Frame, int]] = []
        segment = self._segment
        track = self._track
        for seg in parts:
            if seg:
                got = segment(seg, pos)
                if got is not None:
                    track(got[1].seq, got[1].compat)
                    out.append((*got, pos))
            pos += len(seg) + 1
        self._keep_tail(tail, pos)
        return out

    def feed_columns(self, data: bytes) -> tuple[npt.NDArray[np.void], list[tuple[bytes, Frame]]]:
        """Like :meth:`feed`, for a measurement stream: records and the other frames.

        Returns the measurement records of every MEASUREMENT and
        MEASUREMENT_BATCH frame as a :data:`~rfsas_hw.board.columns.RECORD`
        array in stream order, and the ``(raw, frame)`` pairs of all other
        frames. Counters are those of :meth:`feed`, plus ``bad_payloads`` for
        a measurement frame whose payload is too short (a sender bug, counted
        and skipped).
        """
        measurements: list[tuple[Frame, int]] = []
        others: list[tuple[bytes, Frame]] = []
        for raw, frame, pos in self._feed(data):
            if is_measurement(frame):
                measurements.append((frame, pos))
            else:
                others.append((raw, frame))
        try:
            return records(frame for frame, _ in measurements), others
        except PayloadError:
            pass
        # A sender bug: find the frames at fault, count them and keep the rest.
        good: list[Frame] = []
        for frame, pos in measurements:
            try:
                records([frame])
            except PayloadError as err:
                self.stats.bad_payloads += 1
                self._note(FrameError("payload", str(err)), pos)
                continue
            good.append(frame)
        return records(good), others

    def flush(self) -> None:
        """End of input: count a frame left without its delimiter as truncated."""
        self.new_errors = []
        if self._buf:
            self.stats.truncated += 1
            self.stats.discarded_bytes += len(self._buf)
            self._note(
                FrameError("truncated", f"input ended inside a frame ({len(self._buf)} bytes)"),
                self._offset,
            )
            self._buf = b""

    def reset_sequence(self) -> None:
        """Forget the expected sequence number (after a reconnect)."""
        self._expect = None
        self._buf = b""


class FrameReader:
    """Iterate ``(raw_bytes, message)`` over a byte stream with ``read(n)``.

    Stops when ``read`` returns ``b""``. Counters are in :attr:`stats`.

    Args:
        stream: a binary file, serial port or anything with ``read(n)``.
        chunk_size: bytes asked for per read.
        errors: ``"skip"`` counts bad frames and goes on; ``"raise"`` raises
            :class:`~rfsas_hw.errors.BoardProtocolError` at the first one.
        name: what to call the stream in error messages.
    """

    def __init__(
        self,
        stream: Readable,
        *,
        chunk_size: int = 65536,
        errors: Literal["skip", "raise"] = "skip",
        name: str = "stream",
    ) -> None:
        if errors not in ("skip", "raise"):
            raise ValueError(f"errors must be 'skip' or 'raise', not {errors!r}")
        self.stream = stream
        self.chunk_size = chunk_size
        self.errors = errors
        self.name = name
        self.decoder = FrameDecoder()

    @property
    def stats(self) -> LinkStats:
        """The decoder's counters."""
        return self.decoder.stats

    def _check(self) -> None:
        if self.errors == "raise" and self.decoder.new_errors:
            err = self.decoder.new_errors[0]
            raise BoardProtocolError(f"{self.name}: byte {err.offset}: {err}") from err

    def __iter__(self) -> Iterator[tuple[bytes, Message]]:
        decoder = self.decoder
        while True:
            data = self.stream.read(self.chunk_size)
            if not data:
                decoder.flush()
                self._check()
                return
            frames = decoder.feed(data)
            self._check()
            for raw, frame in frames:
                try:
                    msg = decode_payload(frame)
                except PayloadError as err:
                    self.stats.bad_payloads += 1
                    if len(self.stats.errors) < MAX_KEPT_ERRORS:
                        self.stats.errors.append(f"frame seq {frame.seq}: {err}")
                    if self.errors == "raise":
                        raise BoardProtocolError(f"{self.name}: {err}") from err
                    continue
                yield raw, msg
