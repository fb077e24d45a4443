"""Live 802.11 capture from monitor-mode interfaces: ``wifi:IFACE`` and ``wifi:IFACE_A+IFACE_B``.

Frames are read from a Linux ``AF_PACKET`` raw socket with kernel receive
timestamps (``SO_TIMESTAMPNS``) and decoded by the same vectorised decoder
as capture files; no per-frame packet objects are built.

* The interface must deliver radiotap (``ARPHRD_IEEE80211_RADIOTAP`` = 803),
  which is what a monitor-mode interface does. ``any_link_type=True`` skips
  that check (tests inject radiotap frames on a veth pair).
* ``channels=[1, 6, 11], dwell_s=0.2`` hops the interface over a scan plan
  with ``iw dev IFACE set channel N``.
* ``wifi:A+B`` reads two single-antenna interfaces and pairs their frames
  (see :mod:`rfsas_hw.sources.pairing`); hopping is refused there, since
  both cards must stay on one channel.
"""

from __future__ import annotations

import logging
import select
import shutil
import socket
import struct
import subprocess
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfsas_hw.errors import ConfigError, SourceError, SourceNotAvailableError
from rfsas_hw.records import ObservationBatch
from rfsas_hw.sources.base import Source
from rfsas_hw.sources.frames import LINKTYPE_RADIOTAP, FrameDecoder, FrameSpans, FrameTable
from rfsas_hw.sources.pairing import PairingConfig, pair_tables
from rfsas_hw.sources.schedule import CueScheduler, SchedulerConfig

log = logging.getLogger(__name__)

ARPHRD_ETHER = 1
ARPHRD_IEEE80211 = 801
ARPHRD_IEEE80211_RADIOTAP = 803
ETH_P_ALL = 0x0003
SO_TIMESTAMPNS = 35
PACKET_OUTGOING = 4
SNAPLEN = 65_535
RCVBUF_BYTES = 8 * 1024 * 1024
MAX_FRAMES_PER_READ = 8_192
"""Most frames taken from the socket per read (then they are decoded as one batch)."""
_TIMESPEC = struct.Struct("@qq")

R_OUTGOING = "own transmission (outgoing)"
R_HOP_FAILED = "channel hop failed"

ARPHRD_NAMES = {
    ARPHRD_ETHER: "Ethernet (managed mode or a wired interface)",
    ARPHRD_IEEE80211: "bare 802.11 without radiotap",
    ARPHRD_IEEE80211_RADIOTAP: "radiotap (monitor mode)",
    772: "loopback",
}


def _hint_monitor(name: str) -> str:
    return (
        f"put it in monitor mode, e.g.: ip link set {name} down; "
        f"iw dev {name} set type monitor; ip link set {name} up"
    )


class MonitorSocket:
    """A raw packet socket on one interface, checked for radiotap.

    Args:
        name: interface name (``wlan0mon``).
        any_link_type: accept interfaces that do not deliver radiotap.

    Raises:
        SourceError: no such interface, permission denied, or not in monitor mode.
    """

    def __init__(self, name: str, any_link_type: bool = False) -> None:
        self.name = name
        try:
            socket.if_nametoindex(name)
        except OSError as err:
            raise SourceError(
                f"wifi:{name}: no such interface (list them with: ip link; iw dev)"
            ) from err
        try:
            sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
        except PermissionError as err:
            raise SourceError(
                f"wifi:{name}: permission denied opening a raw socket; run as root or grant "
                "the capability: sudo setcap cap_net_raw,cap_net_admin+eip $(readlink -f "
                "$(which python3))"
            ) from err
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
            sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
            sock.bind((name, ETH_P_ALL))
            hatype = sock.getsockname()[3]
        except OSError as err:
            sock.close()
            raise SourceError(
                f"wifi:{name}: cannot bind a raw socket: {err.strerror or err}"
            ) from err
        self.hatype = int(hatype)
        if self.hatype != ARPHRD_IEEE80211_RADIOTAP and not any_link_type:
            sock.close()
            what = ARPHRD_NAMES.get(self.hatype, "unknown")
            raise SourceError(
                f"wifi:{name}: not in monitor mode: link type {self.hatype} ({what}), expected "
                f"{ARPHRD_IEEE80211_RADIOTAP} (radiotap); {_hint_monitor(name)}"
            )
        sock.setblocking(False)
        self.sock = sock
        self.frames = 0

    def fileno(self) -> int:
        """The socket's file descriptor (for select)."""
        return self.sock.fileno()

    def drain(self, limit: int, skipped: Counter[str]) -> tuple[list[bytes], list[int]]:
        """Every frame waiting on the socket (up to ``limit``) and its kernel time, UTC ns."""
        frames: list[bytes] = []
        stamps: list[int] = []
        recvmsg = self.sock.recvmsg
        space = socket.CMSG_SPACE(_TIMESPEC.size)
        while len(frames) < limit:
            try:
                data, ancdata, _flags, addr = recvmsg(SNAPLEN, space)
            except (BlockingIOError, InterruptedError):
                break
            if addr[2] == PACKET_OUTGOING:
                skipped[R_OUTGOING] += 1
                continue
            t_ns = 0
            for level, kind, payload in ancdata:
                if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
                    sec, nsec = _TIMESPEC.unpack_from(payload)
                    t_ns = sec * 1_000_000_000 + nsec
            frames.append(data)
            stamps.append(t_ns or time.time_ns())
        self.frames += len(frames)
        return frames, stamps

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()


Runner = Callable[[Sequence[str]], "subprocess.CompletedProcess[str]"]


def _run_iw(args: Sequence[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(list(args), capture_output=True, text=True, timeout=5, check=False)


@dataclass(frozen=True)
class ScanPlan:
    """Channels to visit in turn and how long to stay on each."""

    channels: tuple[int, ...]
    """IEEE channel numbers, in visiting order."""
    dwell_s: float
    """Seconds on each channel."""

    def __post_init__(self) -> None:
        if not self.channels:
            raise ConfigError("a scan plan needs at least one channel")
        if self.dwell_s <= 0:
            raise ConfigError(f"dwell must be positive, got {self.dwell_s} s")

    @property
    def cycle_s(self) -> float:
        """Time to visit every channel once, seconds."""
        return self.dwell_s * len(self.channels)

    def channel_at(self, elapsed_s: float) -> int:
        """The channel the plan is on ``elapsed_s`` after it started."""
        return self.channels[int(elapsed_s // self.dwell_s) % len(self.channels)]


class ChannelHopper:
    """Moves an interface along a :class:`ScanPlan` with ``iw``, or as a cue scheduler says.

    Args:
        iface: interface name.
        plan: channels and dwell.
        run: runs a command (``subprocess.run`` by default; tests pass their own).
        clock: monotonic seconds.
        scheduler: a :class:`~rfsas_hw.sources.schedule.CueScheduler` over the same
            plan; its clock is seconds since the hopper started (:meth:`now_s`).

    Raises:
        SourceNotAvailableError: ``iw`` is not installed.
    """

    def __init__(
        self,
        iface: str,
        plan: ScanPlan,
        run: Runner | None = None,
        clock: Callable[[], float] = time.monotonic,
        scheduler: CueScheduler | None = None,
    ) -> None:
        if run is None:
            if shutil.which("iw") is None:
                raise SourceNotAvailableError(
                    "channel hopping needs the iw tool (install it with: apt-get install iw)"
                )
            run = _run_iw
        self.iface = iface
        self.plan = plan
        self.run = run
        self.clock = clock
        self.scheduler = scheduler
        self.current: int | None = None
        self.hops = 0
        self.failures = 0
        self.last_error = ""
        self._start = clock()

    def now_s(self) -> float:
        """Seconds since the hopper started: the clock of its scheduler's cues."""
        return self.clock() - self._start

    def tick(self) -> bool:
        """Switch channel if the plan (or the scheduler) says so; True when a hop was made."""
        if self.scheduler is not None:
            self.scheduler.pull(self.now_s())
            want = self.scheduler.channel_at(self.now_s())
        else:
            want = self.plan.channel_at(self.now_s())
        if want == self.current:
            return False
        result = self.run(["iw", "dev", self.iface, "set", "channel", str(want)])
        self.current = want
        if result.returncode != 0:
            self.failures += 1
            self.last_error = (result.stderr or result.stdout or "").strip()
            if self.failures == 1:
                log.warning(
                    "iw could not set %s to channel %d: %s", self.iface, want, self.last_error
                )
            return False
        self.hops += 1
        return True

    def next_hop_in(self) -> float:
        """Seconds until the plan (or the scheduler) moves on."""
        if self.scheduler is not None:
            return min(self.scheduler.next_change_s(self.now_s()), self.plan.dwell_s)
        elapsed = self.clock() - self._start
        return self.plan.dwell_s - (elapsed % self.plan.dwell_s)


class WifiSource(Source[ObservationBatch]):
    """Observations from one monitor-mode interface, or two paired ones.

    Args:
        spec: ``IFACE`` or ``IFACE_A+IFACE_B``.
        channels: scan plan channels (one interface only); None: stay put.
        dwell_s: seconds per channel when hopping.
        any_link_type: skip the radiotap link-type check (tests on veth pairs).
        n_antennas: RSSI columns (one interface: chain k → column k).
        pairing: options for :class:`~rfsas_hw.sources.pairing.PairingConfig` (two interfaces).
        hold_s: two interfaces: how long frames wait for their partner, seconds.
        run_command: how ``iw`` is run (tests).
        cues: obey cues on the scan plan (:attr:`scheduler`; rules from
            :class:`~rfsas_hw.sources.schedule.SchedulerConfig`).
        errors, filter: see :class:`~rfsas_hw.sources.base.Source`.

    Raises:
        SourceError: an interface is missing, not in monitor mode, or not permitted.
        SourceNotAvailableError: hopping was asked for and ``iw`` is missing.
        ConfigError: hopping with two interfaces, or a bad scan plan.
    """

    scheme = "wifi"

    def __init__(
        self,
        spec: str,
        *,
        channels: Sequence[int] | None = None,
        dwell_s: float = 0.2,
        any_link_type: bool = False,
        n_antennas: int = 2,
        pairing: dict[str, Any] | None = None,
        hold_s: float = 1.0,
        run_command: Runner | None = None,
        cues: SchedulerConfig | None = None,
        **base: Any,
    ) -> None:
        names = [n for n in spec.split("+")]
        if not spec or any(not n for n in names) or len(names) > 2:
            raise ConfigError(f"wifi:{spec}: expected wifi:IFACE or wifi:IFACE_A+IFACE_B")
        if channels and len(names) == 2:
            raise ConfigError("two paired interfaces must stay on one channel: drop --channels")
        plan = ScanPlan(tuple(channels), dwell_s) if channels else None
        if cues is not None and plan is None:
            raise ConfigError("obeying cues needs a scan plan: give --channels")
        scheduler = (
            CueScheduler(plan.channels, plan.dwell_s, cues)
            if plan is not None and cues is not None
            else None
        )
        hopper = (
            ChannelHopper(names[0], plan, run_command, scheduler=scheduler)
            if plan is not None
            else None
        )
        self.sockets: list[MonitorSocket] = []
        try:
            for name in names:
                self.sockets.append(MonitorSocket(name, any_link_type))
        except BaseException:
            for s in self.sockets:
                s.close()
            raise
        super().__init__(**base)
        self.spec = spec
        self.hopper = hopper
        self.decoder = FrameDecoder(n_antennas if len(names) == 1 else 2)
        self.pairing = PairingConfig(**(pairing or {})) if len(names) == 2 else None
        self.hold_ns = int(hold_s * 1e9)
        self._frame_no = [0] * len(names)
        self._pending: list[list[FrameTable]] = [[] for _ in names]
        self.stats.extra["flagged"] = Counter()
        if self.pairing is not None:
            self.stats.extra.update({"paired": 0, "ambiguous_dropped": 0, "pairing_rate": 0.0})
        if plan is not None:
            self.stats.extra["scan_plan"] = f"{list(plan.channels)} × {plan.dwell_s} s"

    @classmethod
    def from_spec(cls, arg: str, **options: Any) -> WifiSource:
        """``wifi:IFACE`` or ``wifi:A+B`` with the keyword options of the constructor."""
        return cls(arg, **options)

    def __repr__(self) -> str:
        return f"WifiSource({self.spec!r})"

    @property
    def scheduler(self) -> CueScheduler | None:
        """The cue scheduler driving the hops (None unless built with ``cues``)."""
        return self.hopper.scheduler if self.hopper is not None else None

    def now_s(self) -> float:
        """The scheduler's clock: seconds since hopping started."""
        return self.hopper.now_s() if self.hopper is not None else 0.0

    # -- reading ---------------------------------------------------------------------

    def _wait(self, timeout: float | None) -> list[int]:
        fds = [s.fileno() for s in self.sockets]
        if self.hopper is not None:
            step = self.hopper.next_hop_in()
            timeout = step if timeout is None else min(timeout, step)
        try:
            ready, _, _ = select.select(fds, [], [], timeout)
        except InterruptedError:
            return []
        return [fds.index(fd) for fd in ready]

    def _decode(self, k: int, frames: list[bytes], stamps: list[int]) -> FrameTable:
        lengths = np.fromiter((len(f) for f in frames), np.int64, len(frames))
        starts = np.concatenate(([0], np.cumsum(lengths)[:-1])).astype(np.int64)
        first = self._frame_no[k] + 1
        self._frame_no[k] += len(frames)
        numbers = np.arange(first, first + len(frames), dtype=np.int64)
        spans = FrameSpans(
            start=starts,
            caplen=lengths,
            t_ns=np.asarray(stamps, np.int64),
            frame_no=numbers,
            file_offset=starts,
            linktype=np.full(len(frames), LINKTYPE_RADIOTAP, np.int32),
        )
        result = self.decoder.decode(b"".join(frames), spans)
        name = f"wifi:{self.sockets[k].name}"
        for problem in result.problems:
            self._bad(problem.reason, problem.error(name))
        for reason, count in result.dropped.items():
            if count:
                self.stats.skip(reason, count=count)
        self.stats.extra["flagged"].update(result.flagged)
        return result.table

    def _read_raw(self, timeout: float | None) -> ObservationBatch | None:
        if self.hopper is not None and self.hopper.tick():
            self.stats.extra["hops"] = self.hopper.hops
        if self.hopper is not None and self.hopper.failures:
            self.stats.extra["hop_failures"] = self.hopper.failures
        if self.scheduler is not None:
            self.stats.extra.update(self.scheduler.stats.as_dict())
        ready = self._wait(timeout)
        tables: list[FrameTable | None] = [None] * len(self.sockets)
        for k in ready:
            frames, stamps = self.sockets[k].drain(MAX_FRAMES_PER_READ, self.stats.skipped)
            if frames:
                tables[k] = self._decode(k, frames, stamps)
        if self.pairing is None:
            table = tables[0]
            if table is None:
                return None
            return table.to_observations(self.stats.extra["flagged"])
        return self._pair(tables)

    def _pair(self, tables: list[FrameTable | None]) -> ObservationBatch | None:
        """Pair frames that have waited ``hold_s``; older unpaired ones are dropped."""
        assert self.pairing is not None
        for k, table in enumerate(tables):
            if table is not None and len(table):
                self._pending[k].append(table)
        if not self._pending[0] or not self._pending[1]:
            return None
        a = FrameTable.concat(self._pending[0], 2)
        b = FrameTable.concat(self._pending[1], 2)
        cutoff = time.time_ns() - self.hold_ns
        ready_a = a.t_ns <= cutoff
        if not ready_a.any():
            self._pending = [[a], [b]]
            return None
        margin = int(self.pairing.host_window_us * 1000) + self.hold_ns
        cand_b = b.t_ns <= cutoff + margin
        result = pair_tables(a.select(ready_a), b.select(cand_b), self.pairing)
        # B frames that were paired, or are too old to pair with anything later, go.
        used = np.zeros(len(b), bool)
        used[np.flatnonzero(cand_b)[result.rows_b]] = True
        stale_b = b.t_ns <= cutoff - margin
        c = result.counters
        self.stats.extra["paired"] += c["paired"]
        self.stats.extra["ambiguous_dropped"] += c["ambiguous"]
        if c["unpaired_a"]:
            self.stats.skip("pairing: unpaired a", count=c["unpaired_a"])
        if c["ambiguous"]:
            self.stats.skip("pairing: ambiguous", count=c["ambiguous"])
        dropped_b = int((stale_b & ~used).sum())
        if dropped_b:
            self.stats.skip("pairing: unpaired b", count=dropped_b)
        seen = self.stats.extra["paired"] + self.stats.skipped["pairing: unpaired a"]
        seen += self.stats.extra["ambiguous_dropped"]
        self.stats.extra["pairing_rate"] = self.stats.extra["paired"] / seen if seen else 0.0
        self._pending = [[a.select(~ready_a)], [b.select(~(used | stale_b))]]
        return result.observations

    def _close(self) -> None:
        for s in self.sockets:
            s.close()
