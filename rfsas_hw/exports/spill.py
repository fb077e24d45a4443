"""Bounded memory for the exports: spooled sections and an external merge sort.

An export of a long run log writes as it reads. Two things still need more
than one record at a time, and both are kept to a byte budget here:

- a section of the output that must come after something known only at the
  end (GeoJSON and KML list the sensors first, then fixes, then bearings):
  :class:`Spool` holds the section's bytes in memory up to the budget, then in
  an anonymous temporary file, and gives them back in blocks;
- output in time order from records that are not (CoT events, ROS 2 messages,
  CPM steps): :class:`ExternalSort` sorts runs of up to the budget in memory,
  writes each to a temporary file and merges them.

Temporary files are unnamed files in the system's temporary directory
(``TMPDIR``), deleted when closed or when the process ends; they hold only what
this process wrote. A temporary file that cannot be written (disk full) is an
:class:`~rfsas_hw.errors.OutputError` naming that directory.
"""

from __future__ import annotations

import heapq
import pickle
import tempfile
from collections.abc import Iterable, Iterator
from typing import IO, Any

from rfsas_hw.closing import ClosingContext
from rfsas_hw.errors import OutputError

__all__ = ["SPILL_BYTES", "ExternalSort", "Spool"]

SPILL_BYTES = 32 * 2**20
"""Bytes a spool or a sort run holds in memory before it goes to a temporary file."""
ITEM_OVERHEAD = 120
"""Bytes a sorted item costs in memory beyond its data (key, tuple, list slot)."""
BLOCK = 2**20
"""Bytes per block a spool gives back."""
FAN_IN = 32
"""Sorted runs on disk before they are merged into one (each open run holds a read buffer)."""

SortKey = tuple[int, ...]


def _failed(err: OSError) -> OutputError:
    where = tempfile.gettempdir()
    return OutputError(f"temporary file in {where}: write failed: {err.strerror or err}")


def _temporary() -> IO[bytes]:
    try:
        return tempfile.TemporaryFile(prefix="rfsas-export.")
    except OSError as err:
        raise _failed(err) from err


class Spool(ClosingContext):
    """Bytes written now and read back once, in memory up to ``max_bytes``.

    Args:
        max_bytes: bytes kept in memory; beyond, everything goes to a temporary file
            (None: :data:`SPILL_BYTES`).
    """

    def __init__(self, max_bytes: int | None = None) -> None:
        self.max_bytes = SPILL_BYTES if max_bytes is None else max_bytes
        self.size = 0
        """Bytes written."""
        self._memory: list[bytes] = []
        self._file: IO[bytes] | None = None

    def write(self, data: bytes) -> None:
        """Append ``data``.

        Raises:
            OutputError: the temporary file cannot be written.
        """
        self.size += len(data)
        try:
            if self._file is not None:
                self._file.write(data)
                return
            self._memory.append(data)
            if self.size > self.max_bytes:
                self._file = _temporary()
                self._file.writelines(self._memory)
                self._memory = []
        except OSError as err:
            raise _failed(err) from err

    def blocks(self) -> Iterator[bytes]:
        """Everything written, in order, in blocks of up to :data:`BLOCK` bytes.

        Raises:
            OutputError: the temporary file cannot be read back.
        """
        if self._file is None:
            yield from self._memory
            return
        try:
            self._file.flush()
            self._file.seek(0)
        except OSError as err:
            raise _failed(err) from err
        while block := self._file.read(BLOCK):
            yield block

    def close(self) -> None:
        """Drop the bytes and the temporary file; idempotent."""
        self._memory = []
        if self._file is not None:
            self._file.close()
            self._file = None


def _read_run(f: IO[bytes]) -> Iterator[tuple[SortKey, int, bytes]]:
    f.seek(0)
    while True:
        try:
            item: tuple[SortKey, int, bytes] = pickle.load(f)  # our own file: never an input
        except EOFError:
            return
        yield item


class ExternalSort(ClosingContext):
    """Sort ``(key, bytes)`` items with at most about ``max_bytes`` of them in memory.

    Items with equal keys come out in the order they were added (the sort is
    stable). Runs of up to ``max_bytes`` are sorted in memory; a full run goes
    to a temporary file (every :data:`FAN_IN` files are merged into one), and
    :meth:`sorted` merges the files and the last run. Nothing touches the disk
    while everything fits in one run.

    Args:
        max_bytes: budget of one in-memory run (item data plus
            :data:`ITEM_OVERHEAD` per item; None: :data:`SPILL_BYTES`).
    """

    def __init__(self, max_bytes: int | None = None) -> None:
        self.max_bytes = SPILL_BYTES if max_bytes is None else max_bytes
        self.count = 0
        """Items added."""
        self.spilled = 0
        """Runs written to temporary files."""
        self._run: list[tuple[SortKey, int, bytes]] = []
        self._run_bytes = 0
        self._files: list[IO[bytes]] = []

    def add(self, key: SortKey, data: bytes) -> None:
        """Add one item.

        Raises:
            OutputError: a temporary file cannot be written.
        """
        self._run.append((key, self.count, data))
        self.count += 1
        self._run_bytes += len(data) + ITEM_OVERHEAD
        if self._run_bytes > self.max_bytes:
            self._spill()

    def _spill(self) -> None:
        self._run.sort()
        self._files.append(self._write(self._run))
        self._run = []
        self._run_bytes = 0
        self.spilled += 1
        if len(self._files) >= FAN_IN:
            # one run of all: as many open runs as the log's length would each hold a buffer
            merged = self._write(heapq.merge(*(_read_run(f) for f in self._files)))
            for f in self._files:
                f.close()
            self._files = [merged]

    @staticmethod
    def _write(items: Iterable[tuple[SortKey, int, bytes]]) -> IO[bytes]:
        f = _temporary()
        try:
            for item in items:
                pickle.dump(item, f, protocol=pickle.HIGHEST_PROTOCOL)
            f.flush()
        except OSError as err:
            f.close()
            raise _failed(err) from err
        return f

    def sorted(self) -> Iterator[bytes]:
        """The data of every item added, in key order (ties in the order added).

        Raises:
            OutputError: a temporary file cannot be read back.
        """
        self._run.sort()
        runs: list[Iterator[Any]] = [iter(self._run)]
        try:
            runs += [_read_run(f) for f in self._files]
            for _, _, data in heapq.merge(*runs):
                yield data
        except OSError as err:
            raise _failed(err) from err

    def close(self) -> None:
        """Drop the items and the temporary files; idempotent."""
        self._run = []
        for f in self._files:
            f.close()
        self._files = []
