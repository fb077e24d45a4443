"""Recording CDR messages: a single MCAP file, or a rosbag2 directory.

Both writers take the same calls (:class:`MessageWriter`): a topic from
:mod:`rfsas_hw.ros2.topics`, a log time and the CDR bytes. The MCAP file uses
the ``ros2`` profile (``ros2msg`` schemas with every dependency, ``cdr``
messages, the offered QoS in each channel's metadata), so Foxglove, the
``mcap`` tools and ``ros2 bag`` (with the MCAP storage plugin) open it. The
rosbag2 directory is written by ``rosbags`` (``metadata.yaml`` plus a
``sqlite3`` or ``mcap`` storage file).
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Any, Literal, Protocol

from rfsas_hw import __version__
from rfsas_hw.errors import ConfigError
from rfsas_hw.optional import require
from rfsas_hw.ros2.topics import Topic
from rfsas_hw.ros2.types import msgdef, type_hash, typestore

RecordFormat = Literal["mcap", "rosbag2"]


class MessageWriter(Protocol):
    """Where serialised messages go (a file, a bag, a live server, DDS)."""

    def write(self, topic: Topic, log_time_ns: int, data: bytes) -> None:
        """Write one CDR message on ``topic``."""
        ...

    def close(self) -> None:
        """Flush and release; idempotent."""
        ...


def qos_yaml(topic: Topic) -> str:
    """The ``offered_qos_profiles`` YAML rosbag2 stores for ``topic`` (numeric enums)."""
    zero = "{sec: 0, nsec: 0}"
    return (
        "- history: 1\n"
        f"  depth: {topic.depth}\n"
        f"  reliability: {1 if topic.reliable else 2}\n"
        f"  durability: {1 if topic.transient_local else 2}\n"
        f"  deadline: {zero}\n"
        f"  lifespan: {zero}\n"
        "  liveliness: 1\n"
        f"  liveliness_lease_duration: {zero}\n"
        "  avoid_ros_namespace_conventions: false\n"
    )


def record_format(path: str | Path, fmt: str | None = None) -> RecordFormat | None:
    """``mcap`` or ``rosbag2`` when ``fmt`` names one or ``path`` ends in ``.mcap``; else None."""
    if fmt is not None:
        name = fmt.lower()
        if name in ("mcap", "rosbag2"):
            return name  # type: ignore[return-value]
        return None
    return "mcap" if Path(path).suffix.lower() == ".mcap" else None


FLUSH_S = 2.0
"""A recording writes what it holds to disk at least this often (seconds of wall
time), so a crash or SIGKILL loses seconds of it, not the run."""


class _Every:
    """True at most once per ``period_s`` of monotonic time."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self._next = time.monotonic() + period_s

    def due(self) -> bool:
        now = time.monotonic()
        if now < self._next:
            return False
        self._next = now + self.period_s
        return True


class McapFileWriter:
    """Write messages into one MCAP file (``ros2`` profile).

    Every :data:`FLUSH_S` the chunk in progress is written out and the file
    flushed: a file cut short by a crash holds every earlier chunk, and the
    ``mcap`` tools (``mcap recover``) or a streaming reader read them.

    Args:
        path: the file to create (replaced if it exists).
        flush_s: write out and flush at least this often, seconds.

    Raises:
        MissingDependencyError: ``mcap`` is not installed.
        ConfigError: the file cannot be created.
    """

    def __init__(self, path: str | Path, flush_s: float = FLUSH_S) -> None:
        writer_mod = require("mcap.writer")
        self._flush = _Every(flush_s)
        self.path = Path(path)
        try:
            self._file: Any = self.path.open("wb")
        except OSError as err:
            raise ConfigError(f"{self.path}: cannot write: {err.strerror or err}") from err
        self._writer: Any = writer_mod.Writer(self._file)
        self._writer.start(profile="ros2", library=f"rfsas-hw {__version__}")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self.messages = 0
        self._closed = False

    def _channel(self, topic: Topic) -> int:
        cid = self._channels.get(topic.name)
        if cid is not None:
            return cid
        sid = self._schemas.get(topic.typename)
        if sid is None:
            sid = self._writer.register_schema(
                name=topic.typename, encoding="ros2msg", data=msgdef(topic.typename).encode()
            )
            self._schemas[topic.typename] = sid
        cid = self._writer.register_channel(
            topic=topic.name,
            message_encoding="cdr",
            schema_id=sid,
            metadata={
                "offered_qos_profiles": qos_yaml(topic),
                "topic_type_hash": type_hash(topic.typename),
            },
        )
        self._channels[topic.name] = cid
        return int(cid)

    def write(self, topic: Topic, log_time_ns: int, data: bytes) -> None:
        """Add one message; ``log_time_ns`` is its log and publish time."""
        if self._closed:
            raise ConfigError(f"{self.path}: writer is closed")
        cid = self._channel(topic)
        seq = self._seq.get(topic.name, 0)
        self._seq[topic.name] = seq + 1
        self._writer.add_message(
            channel_id=cid,
            log_time=int(log_time_ns),
            data=data,
            publish_time=int(log_time_ns),
            sequence=seq,
        )
        self.messages += 1
        if self._flush.due():
            self._writer.flush()

    def close(self) -> None:
        """Write the summary and close the file; idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._file.close()


class Rosbag2Writer:
    """Write messages into a rosbag2 directory with ``rosbags``.

    With ``sqlite3`` storage the rows are committed every :data:`FLUSH_S`, so a
    crash keeps them (``ros2 bag reindex`` then rebuilds ``metadata.yaml``,
    which is written on close).

    Args:
        path: the directory to create; it must not exist (rosbag2's rule),
            unless ``overwrite``.
        storage: ``sqlite3`` (readable by every ROS 2 release) or ``mcap``.
        overwrite: remove an existing directory first.
        flush_s: commit at least this often, seconds.

    Raises:
        MissingDependencyError: ``rosbags`` is not installed.
        ConfigError: the directory exists, or cannot be created.
    """

    def __init__(
        self,
        path: str | Path,
        storage: str = "sqlite3",
        *,
        overwrite: bool = False,
        flush_s: float = FLUSH_S,
    ) -> None:
        rosbag2 = require("rosbags.rosbag2")
        self.path = Path(path)
        if self.path.exists():
            if not overwrite:
                raise ConfigError(f"{self.path}: exists; a rosbag2 directory must be new")
            shutil.rmtree(self.path)
        plugins = {"sqlite3": rosbag2.StoragePlugin.SQLITE3, "mcap": rosbag2.StoragePlugin.MCAP}
        if storage not in plugins:
            raise ConfigError(f"rosbag2 storage {storage!r}: expected sqlite3 or mcap")
        self._writer: Any = rosbag2.Writer(self.path, version=9, storage_plugin=plugins[storage])
        try:
            self._writer.open()
        except Exception as err:  # rosbags raises WriterError or OSError
            raise ConfigError(f"{self.path}: cannot create the bag: {err}") from err
        self._connections: dict[str, Any] = {}
        self.messages = 0
        self._closed = False
        self._commit = _Every(flush_s)

    def _connection(self, topic: Topic) -> Any:
        conn = self._connections.get(topic.name)
        if conn is None:
            conn = self._writer.add_connection(
                topic.name,
                topic.typename,
                typestore=typestore(),
                serialization_format="cdr",
                offered_qos_profiles=[_rosbags_qos(topic)],
            )
            self._connections[topic.name] = conn
        return conn

    def write(self, topic: Topic, log_time_ns: int, data: bytes) -> None:
        """Add one message with receive time ``log_time_ns``."""
        if self._closed:
            raise ConfigError(f"{self.path}: writer is closed")
        self._writer.write(self._connection(topic), int(log_time_ns), data)
        self.messages += 1
        if self._commit.due():
            # the sqlite3 storage holds one transaction until close; committing
            # it now and then keeps the rows of a run that crashes
            conn = getattr(getattr(self._writer, "storage", None), "conn", None)
            if conn is not None:
                conn.commit()

    def close(self) -> None:
        """Write ``metadata.yaml`` and close the storage; idempotent."""
        if self._closed:
            return
        self._closed = True
        self._writer.close()


def _rosbags_qos(topic: Topic) -> Any:
    iface = require("rosbags.interfaces")
    zero = iface.QosTime(sec=0, nsec=0)
    return iface.Qos(
        history=iface.QosHistory.KEEP_LAST,
        depth=topic.depth,
        reliability=(
            iface.QosReliability.RELIABLE if topic.reliable else iface.QosReliability.BEST_EFFORT
        ),
        durability=(
            iface.QosDurability.TRANSIENT_LOCAL
            if topic.transient_local
            else iface.QosDurability.VOLATILE
        ),
        deadline=zero,
        lifespan=zero,
        liveliness=iface.QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=zero,
        avoid_ros_namespace_conventions=False,
    )


def open_recording(
    path: str | Path, fmt: RecordFormat, *, storage: str = "sqlite3", overwrite: bool = False
) -> McapFileWriter | Rosbag2Writer:
    """An MCAP file writer (replacing a file) or a rosbag2 directory writer (a new
    directory unless ``overwrite``) at ``path``.

    Raises:
        ConfigError / MissingDependencyError: see the writer classes.
    """
    if fmt == "mcap":
        return McapFileWriter(path)
    return Rosbag2Writer(path, storage, overwrite=overwrite)
