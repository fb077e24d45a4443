"""``serial:URL`` — a DF board on a serial line, speaking ``firmware_protocol/SPEC.md``.

The port is opened with :func:`serial.serial_for_url`, so device paths
(``/dev/ttyUSB0``), ``loop://``, ``spy://`` (hex dump of the traffic) and
``socket://HOST:PORT`` all work. On open the driver says HELLO, syncs the
board clock, sets the scan plan (or channel) and starts streaming; it then
yields :class:`~rfsas_hw.records.ObservationBatch` values with host UTC
times. When the device disappears (USB unplug, emulator disconnect) it logs
a warning and reconnects with exponential backoff, re-running the handshake.

Driver options can be given as keyword arguments or after ``#`` in the spec:
``serial:/dev/ttyUSB0#baud=115200,channels=1+6+11,dwell_ms=150``.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import serial

from rfsas_hw.board.codec import Encoder, decode_payload, message_name
from rfsas_hw.board.columns import to_observations
from rfsas_hw.board.framing import Frame
from rfsas_hw.board.messages import (
    Ack,
    CompatFlag,
    ErrorCode,
    ErrorReport,
    Heartbeat,
    Hello,
    Info,
    Message,
    Nak,
    NakCode,
    PayloadError,
    SetChannel,
    SetScanPlan,
    Start,
    Stop,
    TimeSync,
    TimeSyncRequest,
)
from rfsas_hw.board.reader import FrameDecoder
from rfsas_hw.board.timesync import TimeMapper
from rfsas_hw.errors import BoardProtocolError, ConfigError, SourceError
from rfsas_hw.records import ObservationBatch
from rfsas_hw.rf.channels import channel_to_freq_mhz
from rfsas_hw.sources.base import BatchFilter, ErrorPolicy, Source
from rfsas_hw.sources.schedule import CueScheduler, SchedulerConfig

log = logging.getLogger(__name__)

PortFactory = Callable[..., Any]

_OPTION_TYPES: dict[str, Callable[[str], Any]] = {
    "baud": int,
    "baudrate": int,
    "channel": int,
    "channels": lambda v: [int(c) for c in v.replace("+", " ").split()],
    "dwell_ms": int,
    "reconnect": lambda v: v.lower() in ("1", "true", "yes", "on"),
    "time_sync_s": float,
}


def parse_options(text: str) -> dict[str, Any]:
    """``key=value,key=value`` after ``#`` in a spec → keyword arguments.

    Raises:
        ConfigError: an unknown key or a malformed value.
    """
    out: dict[str, Any] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, sep, value = part.partition("=")
        conv = _OPTION_TYPES.get(key.strip())
        if not sep or conv is None:
            raise ConfigError(
                f"serial option {part!r}: use key=value with keys {', '.join(_OPTION_TYPES)}"
            )
        try:
            out["baudrate" if key.strip() == "baud" else key.strip()] = conv(value.strip())
        except ValueError as err:
            raise ConfigError(f"serial option {part!r}: {err}") from err
    return out


class SerialSource(Source[ObservationBatch]):
    """Observations from a DF board over a serial line.

    Args:
        url: device path or pyserial URL.
        baudrate: line rate, bit/s.
        channel: Wi-Fi channel to listen on (ignored when ``channels`` is given).
        channels: Wi-Fi channels to scan, ``dwell_ms`` each.
        dwell_ms: time per channel of the scan plan, ms.
        start: start streaming after the handshake (False: only handshake,
            for ``rfsas board info``).
        reconnect: reconnect when the device disappears (False: end the source).
        handshake_timeout_s: wait for each answer, seconds.
        retries: tries per command.
        backoff_s: first reconnect delay, seconds (doubles up to ``max_backoff_s``).
        max_backoff_s: longest reconnect delay, seconds.
        time_sync_s: seconds between clock syncs while streaming.
        batch_s: once measurements arrive, keep reading this long (within the
            read timeout) to hand out fewer, larger batches, seconds.
        silence_s: with no byte from the board for this long, repeat the
            handshake (and reconnect if that fails), seconds.
        port_factory: opens the port (default :func:`serial.serial_for_url`).
        cues: obey cues on the scan plan (:attr:`scheduler`): the host drives the
            board's scan-plan command, a one-channel plan for a cue dwell, then
            the plan again from the channel it left.
        errors: ``skip`` counts bad frames; ``raise`` raises the first one.
        filter: optional keep-mask function per batch.

    Raises:
        SourceError: the port cannot be opened or the board does not answer.
    """

    scheme = "serial"

    def __init__(
        self,
        url: str,
        *,
        baudrate: int = 921_600,
        channel: int | None = None,
        channels: Sequence[int] | None = None,
        dwell_ms: int = 200,
        start: bool = True,
        reconnect: bool = True,
        handshake_timeout_s: float = 0.5,
        retries: int = 3,
        backoff_s: float = 0.1,
        max_backoff_s: float = 5.0,
        time_sync_s: float = 10.0,
        batch_s: float = 0.02,
        silence_s: float = 5.0,
        port_factory: PortFactory | None = None,
        cues: SchedulerConfig | None = None,
        errors: ErrorPolicy = "skip",
        filter: BatchFilter | None = None,
    ) -> None:
        super().__init__(errors=errors, filter=filter)
        self._closed = True  # until the port is open: no ResourceWarning for a failed open
        url, _, opts = url.partition("#")
        if opts:
            o = parse_options(opts)
            baudrate = o.get("baudrate", baudrate)
            channel = o.get("channel", channel)
            channels = o.get("channels", channels)
            dwell_ms = o.get("dwell_ms", dwell_ms)
            reconnect = o.get("reconnect", reconnect)
            time_sync_s = o.get("time_sync_s", time_sync_s)
        if not url:
            raise ConfigError("serial source needs a device path or URL, e.g. serial:/dev/ttyUSB0")
        self.url = url
        self.baudrate = baudrate
        self.freqs_mhz = tuple(channel_to_freq_mhz(c) for c in channels or ())
        self.freq_mhz = channel_to_freq_mhz(channel) if channel is not None else None
        if not 0 < dwell_ms <= 0xFFFF:
            raise ConfigError(f"dwell_ms {dwell_ms} outside 1..65535")
        self.dwell_ms = dwell_ms
        if cues is not None and not channels:
            raise ConfigError("obeying cues needs a scan plan: give channels")
        self.scheduler = (
            CueScheduler(tuple(channels or ()), dwell_ms / 1e3, cues) if cues is not None else None
        )
        self._sched_t0 = time.monotonic()
        self._commanded: int | None = None
        self.start_streaming = start
        self.reconnect = reconnect
        self.handshake_timeout_s = handshake_timeout_s
        self.retries = retries
        self.backoff_s = backoff_s
        self.max_backoff_s = max_backoff_s
        self.time_sync_s = time_sync_s
        self.batch_s = batch_s
        self.silence_s = silence_s
        self._heard_at = time.monotonic()
        self._factory: PortFactory = port_factory or serial.serial_for_url
        self.decoder = FrameDecoder()
        self.clock = TimeMapper()
        self.info: Info | None = None
        self.heartbeat: Heartbeat | None = None
        self._encoder = Encoder()
        self._port: Any = None
        # records with their host times, mapped on arrival: a later reboot
        # or re-sync must not re-map what was measured before it
        self._pending: list[tuple[npt.NDArray[np.void], npt.NDArray[np.int64]]] = []
        self._configured = False
        self._restarted = False
        self._next_sync = 0.0
        self._next_attempt = 0.0
        self._backoff = backoff_s
        self._down_since: float | None = None
        self.stats.extra.update(
            disconnects=0, reconnects=0, board_restarts=0, error_reports=0, naks=0, silences=0
        )
        self._connect()
        self._closed = False

    # -- connection -------------------------------------------------------------

    def _connect(self) -> None:
        try:
            self._port = self._factory(self.url, baudrate=self.baudrate, timeout=0.02)
        except (serial.SerialException, OSError, ValueError) as err:
            raise SourceError(f"cannot open serial port {self.url!r}: {err}") from err
        try:
            self._handshake()
        except BaseException:
            self._drop_port()
            raise

    def _drop_port(self) -> None:
        port, self._port = self._port, None
        if port is None:
            return
        try:
            port.close()
        except (serial.SerialException, OSError) as err:
            log.debug("closing %s: %s", self.url, err)
        # pyserial's spy:// wrapper never closes the trace file it opened
        trace = getattr(getattr(port, "formatter", None), "output", None)
        if trace is not None and trace not in (sys.stderr, sys.stdout):
            trace.close()

    def _handshake(self) -> None:
        self._configured = False
        self.decoder.reset_sequence()
        self.clock.reset()
        info = self._request(Hello(1), Info)
        assert isinstance(info, Info)
        self.info = info
        for _ in range(4):
            self._request(TimeSyncRequest(time.time_ns()), TimeSync)
        if self.freqs_mhz:
            self._request(SetScanPlan(self.dwell_ms, self.freqs_mhz), Ack)
        elif self.freq_mhz is not None:
            self._request(SetChannel(self.freq_mhz), Ack)
        if self.start_streaming:
            self._request(Start(), Ack)
        self._next_sync = time.monotonic() + self.time_sync_s
        self._heard_at = time.monotonic()
        self._commanded = None
        self._configured = True
        self._restarted = False

    def _write(self, msg: Message) -> int:
        seq = self._encoder.seq
        self._port.write(self._encoder.encode(msg))
        return seq

    def _request(self, msg: Message, want: type[Message]) -> Message:
        """Send a command and wait for its answer, keeping whatever else arrives.

        Raises:
            SourceError: no answer after the retries, or a NAK.
        """
        name = message_name(msg.TYPE)
        for _ in range(self.retries):
            if isinstance(msg, TimeSyncRequest):
                msg = TimeSyncRequest(time.time_ns())
            seq = self._write(msg)
            deadline = time.monotonic() + self.handshake_timeout_s
            while time.monotonic() < deadline:
                for answer in self._pump():
                    if isinstance(answer, Nak) and answer.acked_seq == seq:
                        code = (
                            NakCode(answer.error).name
                            if answer.error in NakCode._value2member_map_
                            else str(answer.error)
                        )
                        raise SourceError(
                            f"board at {self.url} refused {name}: {code} (detail {answer.detail})"
                        )
                    if isinstance(answer, want) and (
                        not isinstance(answer, Ack) or answer.acked_seq == seq
                    ):
                        return answer
        raise SourceError(
            f"board at {self.url} did not answer {name} within {self.handshake_timeout_s} s "
            f"({self.retries} tries): check the port, the baud rate ({self.baudrate}) and the power"
        )

    # -- reading ---------------------------------------------------------------

    def _pump(self) -> list[Message]:
        """Read what is there; queue measurement frames, handle and return the rest."""
        port = self._port
        data = port.read(max(1, port.in_waiting))
        if not data:
            return []
        self._heard_at = time.monotonic()
        arrival = time.time_ns()
        out: list[Message] = []
        recs, others = self.decoder.feed_columns(data)
        if len(recs):
            t_us = recs["t_us"]
            self.clock.observe_arrival(int(t_us.max()), arrival)
            self._pending.append((recs, self.clock.to_host_ns(t_us)))
        for _, frame in others:
            try:
                msg = decode_payload(frame)
            except PayloadError as err:
                self.decoder.stats.bad_payloads += 1
                self._bad("payload", BoardProtocolError(f"{self.url}: {err}"))
                continue
            self._handle(msg, frame, arrival)
            out.append(msg)
        for ferr in self.decoder.new_errors:
            self._bad(ferr.kind, BoardProtocolError(f"{self.url}: byte {ferr.offset}: {ferr}"))
        return out

    def _handle(self, msg: Message, frame: Frame, arrival_ns: int) -> None:
        if isinstance(msg, TimeSync):
            # the echoed host time is the request's send time
            self.clock.add(msg.host_time_ns, arrival_ns, msg.board_rx_us, msg.board_tx_us)
        elif isinstance(msg, Heartbeat):
            self.heartbeat = msg
        elif isinstance(msg, ErrorReport):
            self.stats.extra["error_reports"] += 1
            code = (
                ErrorCode(msg.code).name if msg.code in ErrorCode._value2member_map_ else msg.code
            )
            log.warning("board %s reports %s (detail %d): %s", self.url, code, msg.detail, msg.text)
        elif isinstance(msg, Nak):
            self.stats.extra["naks"] += 1
        elif isinstance(msg, Info) and frame.compat & CompatFlag.RESTART and self._configured:
            self._restarted = True

    def _read_raw(self, timeout: float | None) -> ObservationBatch | None:
        wait = 0.1 if timeout is None else timeout
        if self._port is None and not self._try_reconnect(wait):
            return None
        start = time.monotonic()
        deadline = start + wait
        first: float | None = None
        try:
            while True:
                self._pump()
                self._follow_schedule()
                if self._restarted:
                    self._restarted = False
                    self.stats.extra["board_restarts"] += 1
                    log.warning("board at %s restarted; configuring it again", self.url)
                    self._handshake()
                now = time.monotonic()
                if now - self._heard_at > self.silence_s:
                    # heartbeats come every second: a board this quiet is hung
                    # or was re-flashed; ask it again, reconnect if it stays mute
                    self.stats.extra["silences"] += 1
                    log.warning(
                        "board at %s silent for %.1f s; asking it again", self.url, self.silence_s
                    )
                    self._handshake()
                    now = time.monotonic()
                if self.start_streaming and now >= self._next_sync:
                    self._write(TimeSyncRequest(time.time_ns()))
                    self._next_sync = now + self.time_sync_s
                if self._pending and first is None:
                    first = now
                # gather for a short window: fewer, larger batches cost less per frame
                if now >= deadline or (first is not None and now - first >= self.batch_s):
                    break
        except (serial.SerialException, OSError) as err:
            self._lost(err)
            return self._flush()
        except SourceError as err:
            self._lost(err)
            return self._flush()
        return self._flush()

    def now_s(self) -> float:
        """The scheduler's clock: seconds since the source was opened."""
        return time.monotonic() - self._sched_t0

    def _follow_schedule(self) -> None:
        """Command the board when the scheduler starts or ends a cue dwell."""
        sched = self.scheduler
        if sched is None or self._port is None or not self._configured:
            return
        sched.pull(self.now_s())
        sched.channel_at(self.now_s())
        cue = sched.cued
        want = cue.channel if cue is not None else None
        if want == self._commanded:
            return
        if cue is not None:
            freqs: tuple[int, ...] = (channel_to_freq_mhz(cue.channel),)
        else:
            # the plan again, starting from the channel the scheduler resumes on
            here = sched.channels.index(sched.channel_at(self.now_s()))
            order = sched.channels[here:] + sched.channels[:here]
            freqs = tuple(channel_to_freq_mhz(c) for c in order)
        # not waited for: the ACK (or a NAK, counted) arrives with the next reads
        self._write(SetScanPlan(self.dwell_ms, freqs))
        self._commanded = want
        self.stats.extra.update(sched.stats.as_dict())

    def _flush(self) -> ObservationBatch | None:
        self._publish_counters()
        if not self._pending:
            return None
        parts, self._pending = self._pending, []
        if len(parts) == 1:
            rec, t_ns = parts[0]
        else:
            rec = np.concatenate([p[0] for p in parts])
            t_ns = np.concatenate([p[1] for p in parts])
        n_ant = self.info.n_antennas if self.info is not None else 2
        return to_observations(rec, t_ns, max(1, min(n_ant, 4)))

    def _publish_counters(self) -> None:
        link = self.decoder.stats
        extra = self.stats.extra
        for key in (
            "crc_errors",
            "resyncs",
            "discarded_bytes",
            "unknown_types",
            "incompatible",
            "bad_payloads",
            "sequence_gaps",
            "lost",
            "restarts",
        ):
            extra[key] = getattr(link, key)
        extra["link_frames"] = link.frames
        extra["bytes"] = link.bytes
        extra["clock_offset_ns"] = round(self.clock.offset_ns)
        extra["clock_rate_ppm"] = round(self.clock.rate_ppm, 3)
        hb = self.heartbeat
        if hb is not None:
            extra["board_frames_heard"] = hb.frames_heard
            extra["board_frames_dropped"] = hb.frames_dropped
            extra["board_queue_depth"] = hb.queue_depth

    # -- disconnects -------------------------------------------------------------

    def _lost(self, err: Exception) -> None:
        self._drop_port()
        self.stats.extra["disconnects"] += 1
        self._down_since = time.monotonic()
        if not self.reconnect:
            log.warning("board at %s disconnected (%s)", self.url, err)
            self.stats.errors.append(f"{self.url}: disconnected: {err}")
            self._end()
            return
        log.warning("board at %s disconnected (%s); reconnecting", self.url, err)
        self._backoff = self.backoff_s
        self._next_attempt = time.monotonic() + self._backoff

    def _try_reconnect(self, wait: float) -> bool:
        now = time.monotonic()
        if now < self._next_attempt:
            time.sleep(min(wait, self._next_attempt - now))
            if time.monotonic() < self._next_attempt:
                return False
        try:
            self._connect()
        except SourceError as err:
            self._backoff = min(self._backoff * 2, self.max_backoff_s)
            self._next_attempt = time.monotonic() + self._backoff
            log.info(
                "reconnect to %s failed (%s); next try in %.1f s", self.url, err, self._backoff
            )
            return False
        down = time.monotonic() - (self._down_since or time.monotonic())
        self.stats.extra["reconnects"] += 1
        log.warning("board at %s reconnected after %.1f s", self.url, down)
        return True

    @property
    def connected(self) -> bool:
        """True while the port is open."""
        return self._port is not None

    def _close(self) -> None:
        if self._port is not None and self.start_streaming:
            try:
                self._write(Stop())
            except (serial.SerialException, OSError) as err:
                log.debug("stop on close: %s", err)
        self._drop_port()


def board_info(url: str, **options: Any) -> tuple[Info, dict[str, Any]]:
    """Handshake only: the board's INFO and the clock/link facts.

    Raises:
        SourceError: the port cannot be opened or the board does not answer.
    """
    src = SerialSource(url, start=False, reconnect=False, **options)
    try:
        assert src.info is not None
        facts = {
            "clock_offset_ns": round(src.clock.offset_ns),
            "best_rtt_us": round(min(s.rtt_ns for s in src.clock.samples) / 1000, 1)
            if src.clock.samples
            else None,
            "crc_errors": src.decoder.stats.crc_errors,
        }
        return src.info, facts
    finally:
        src.close()


__all__ = ["SerialSource", "board_info", "parse_options"]
