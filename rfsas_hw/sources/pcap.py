"""Recorded captures as a source: ``pcap:PATH``, ``pcap:-`` (stdin), ``pcap:A.pcap+B.pcap``.

* ``pcap:capture.pcapng`` reads a pcap or pcapng file (radiotap or bare
  802.11) as fast as it can, in large blocks.
* ``pcap:-`` reads a pcap stream from standard input as it arrives, e.g.
  ``tcpdump -i wlan0mon -w - | rfsas live pcap:-``; reads honour the timeout.
* ``pcap:a.pcap+b.pcap`` pairs the frames of two single-antenna receivers
  (see :mod:`rfsas_hw.sources.pairing`): receiver A's signal becomes antenna
  column 0, B's column 1.
"""

from __future__ import annotations

import os
import select
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from rfsas_hw.errors import SourceError
from rfsas_hw.records import ObservationBatch
from rfsas_hw.sources.base import Source
from rfsas_hw.sources.frames import DEFAULT_VECTOR_MIN, FrameDecoder, FrameSpans, FrameTable
from rfsas_hw.sources.pcapfile import CaptureParser, FrameProblem

BLOCK_BYTES = 8 * 1024 * 1024
"""Bytes read from a file per call."""
PIPE_BYTES = 1024 * 1024
"""Most bytes taken from a pipe per call."""
CHUNK_FRAMES = 65_536
"""Most frames decoded per batch."""


@dataclass(slots=True)
class FrameRead:
    """One step of a :class:`FrameStream`: decoded frames and what was lost."""

    table: FrameTable
    problems: list[FrameProblem] = field(default_factory=list)
    dropped: Counter[str] = field(default_factory=Counter)
    flagged: Counter[str] = field(default_factory=Counter)


class FrameStream:
    """A capture file or pipe, read in blocks and decoded to :class:`FrameTable` chunks.

    Args:
        path: file path, or ``-`` for standard input.
        n_antennas: per-chain columns to keep.
        vector_min: smallest batch decoded with numpy gathers.
        stream: an already open binary stream to read instead of ``path``.

    Raises:
        SourceError: the file cannot be opened.
    """

    def __init__(
        self,
        path: str,
        n_antennas: int = 2,
        vector_min: int = DEFAULT_VECTOR_MIN,
        stream: BinaryIO | None = None,
    ) -> None:
        self.path = path
        self.name = "<stdin>" if path == "-" else path
        self.decoder = FrameDecoder(n_antennas, vector_min)
        self.parser = CaptureParser(self.name)
        self.total_bytes: int | None = None
        self.eof = False
        self._owned = False
        if stream is not None:
            self._stream: BinaryIO = stream
        elif path == "-":
            self._stream = sys.stdin.buffer
        else:
            try:
                self._stream = open(path, "rb")  # noqa: SIM115 - closed in close()
            except FileNotFoundError as err:
                raise SourceError(f"{path}: no such capture file") from err
            except IsADirectoryError as err:
                raise SourceError(f"{path}: is a directory, not a capture file") from err
            except PermissionError as err:
                raise SourceError(f"{path}: permission denied") from err
            self._owned = True
            self.total_bytes = Path(path).stat().st_size
        self._pipe = path == "-" or not self._owned
        # A regular file is re-read from the first unconsumed byte (see CaptureParser.refeed).
        self._seekable = self._owned and self._stream.seekable()
        try:
            self._fd: int | None = self._stream.fileno()
        except (OSError, AttributeError, ValueError):
            self._fd = None

    @property
    def bytes_read(self) -> int:
        """Stream bytes consumed so far."""
        return self.parser.position

    def _fill(self, timeout: float | None) -> bool:
        """Read more input; False when nothing arrived before the timeout."""
        if self._pipe and self._fd is not None:
            if timeout is not None:
                ready, _, _ = select.select([self._fd], [], [], timeout)
                if not ready:
                    return False
            data = os.read(self._fd, PIPE_BYTES)
        elif self._seekable:
            kept = self.parser.buffered
            self._stream.seek(self.parser.position)
            data = self._stream.read(kept + BLOCK_BYTES)
            if len(data) <= kept:
                self.eof = True
            else:
                self.parser.refeed(data)
            return True
        else:
            data = self._stream.read(BLOCK_BYTES)
        if not data:
            self.eof = True
        else:
            self.parser.feed(data)
        return True

    def read(self, timeout: float | None = None) -> FrameRead | None:
        """The next decoded chunk; None on timeout or when the capture has ended (see ``eof``).

        Raises:
            CaptureFormatError: the input is not a capture at all.
        """
        while True:
            chunk = self.parser.next_chunk(final=self.eof, max_frames=CHUNK_FRAMES)
            if chunk is not None:
                spans = FrameSpans(
                    chunk.start,
                    chunk.caplen,
                    chunk.t_ns,
                    chunk.frame_no,
                    chunk.file_offset,
                    chunk.linktype,
                )
                result = self.decoder.decode(chunk.buf, spans)
                problems = sorted(chunk.problems + result.problems, key=lambda p: p.frame_no)
                return FrameRead(result.table, problems, result.dropped, result.flagged)
            if self.eof:
                return None
            if not self._fill(timeout):
                return None

    def close(self) -> None:
        """Close the file (standard input is left open)."""
        if self._owned:
            self._stream.close()


def read_frames(path: str, n_antennas: int = 2) -> tuple[FrameTable, FrameRead]:
    """Every frame of a capture file, with the problems met (for offline tools).

    Returns the concatenated table and a :class:`FrameRead` whose ``table`` is
    empty and whose counters cover the whole file.

    Raises:
        SourceError: the file cannot be opened.
        CaptureFormatError: the file is not a capture.
    """
    stream = FrameStream(path, n_antennas)
    tables: list[FrameTable] = []
    total = FrameRead(FrameTable.allocate(0, n_antennas))
    try:
        while True:
            got = stream.read()
            if got is None:
                break
            tables.append(got.table)
            total.problems.extend(got.problems)
            total.dropped.update(got.dropped)
            total.flagged.update(got.flagged)
    finally:
        stream.close()
    return FrameTable.concat(tables, n_antennas), total


class PcapSource(Source[ObservationBatch]):
    """Observations from a pcap/pcapng file, standard input, or two paired files.

    Args:
        path: a file, ``-`` for standard input, or ``A+B`` for two receivers to pair.
        n_antennas: RSSI columns per observation (chain ``k`` → column ``k``).
        vector_min: smallest batch decoded with numpy gathers (tests lower it).
        stream: read this binary stream instead of opening ``path``.
        pairing: options for :class:`~rfsas_hw.sources.pairing.PairingConfig` (``A+B`` only).
        errors, filter: see :class:`~rfsas_hw.sources.base.Source`.

    Counters: ``stats.skipped`` by reason (malformed frames, bad FCS, frames
    without transmitter, …); ``stats.extra["flagged"]`` frames kept with a
    quality flag; ``stats.extra["bytes_read"]`` / ``["bytes_total"]`` for progress.

    Raises:
        SourceError: a file cannot be opened.
    """

    scheme = "pcap"

    def __init__(
        self,
        path: str,
        *,
        n_antennas: int = 2,
        vector_min: int = DEFAULT_VECTOR_MIN,
        stream: BinaryIO | None = None,
        pairing: dict[str, Any] | None = None,
        **base: Any,
    ) -> None:
        if not path:
            raise SourceError("pcap source needs a path: pcap:FILE, pcap:- or pcap:A.pcap+B.pcap")
        self.path = path
        self.n_antennas = n_antennas
        self._paired: Any = None
        self._paired_started = False
        self._stream: FrameStream | None = None
        # Open the input before the base class exists: a failed open leaves nothing to close.
        parts = path.split("+") if path != "-" and not Path(path).exists() else [path]
        if len(parts) == 2 and all(parts):
            from rfsas_hw.sources.pairing import OfflinePairing, PairingConfig

            config = PairingConfig(**(pairing or {}))
            self._paired = OfflinePairing(parts[0], parts[1], config)
        elif len(parts) > 2:
            raise SourceError(f"pcap:{path}: pair at most two captures (A.pcap+B.pcap)")
        else:
            self._stream = FrameStream(path, n_antennas, vector_min, stream)
        super().__init__(**base)
        flagged: Counter[str] = Counter()
        self.stats.extra["flagged"] = flagged
        self.stats.extra["bytes_read"] = 0
        self.stats.extra["bytes_total"] = self._stream.total_bytes if self._stream else None

    def __repr__(self) -> str:
        return f"PcapSource({self.path!r})"

    def _read_raw(self, timeout: float | None) -> ObservationBatch | None:
        if self._paired is not None:
            return self._read_paired()
        assert self._stream is not None
        got = self._stream.read(timeout)
        self.stats.extra["bytes_read"] = self._stream.bytes_read
        if got is None:
            if self._stream.eof:
                self._end()
            return None
        for problem in got.problems:
            self._bad(problem.reason, problem.error(self._stream.name))
        for reason, count in got.dropped.items():
            if count:
                self.stats.skip(reason, count=count)
        flagged: Counter[str] = self.stats.extra["flagged"]
        obs = got.table.to_observations(flagged)
        flagged.update(got.flagged)
        return obs

    def _read_paired(self) -> ObservationBatch | None:
        paired = self._paired
        if not self._paired_started:
            self._paired_started = True
            for path, problem in paired.problems:
                self._bad(problem.reason, problem.error(path))
            for reason, count in paired.dropped.items():
                self.stats.skip(reason, count=count)
            unpaired = paired.result.counters
            for reason in ("ambiguous", "unpaired_a", "unpaired_b"):
                if unpaired[reason]:
                    self.stats.skip(f"pairing: {reason.replace('_', ' ')}", count=unpaired[reason])
            self.stats.extra.update(paired.extra)
        batch: ObservationBatch | None = paired.next_batch()
        if batch is None:
            self._end()
        return batch

    def _close(self) -> None:
        if self._stream is not None:
            self._stream.close()
        if self._paired is not None:
            self._paired.close()
