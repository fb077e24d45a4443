"""The live scene over Foxglove's WebSocket protocol (``rfsas backend --foxglove``).

Every topic of :mod:`rfsas_hw.ros2.topics` becomes a channel with its
``ros2msg`` schema and ``cdr`` encoding: the Foxglove app decodes the same
bytes a bag holds and draws the markers and transforms in its 3D panel. The
server binds to the loopback interface unless told otherwise; it has no
authentication, so exposing it on a network is the operator's decision.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from rfsas_hw.errors import ConfigError
from rfsas_hw.optional import require
from rfsas_hw.ros2 import topics
from rfsas_hw.ros2.bag import qos_yaml
from rfsas_hw.ros2.topics import Topic
from rfsas_hw.ros2.types import msgdef

log = logging.getLogger(__name__)

DEFAULT_PORT = 8765
"""Foxglove's usual WebSocket port."""

LAYOUT_FILE = Path(__file__).resolve().parent / "layouts" / "rfsas.foxglove.json"
"""The shipped Foxglove layout: 3D scene in ``map``, assessments, risk plot, link diagnostics."""


class FoxgloveServer:
    """A Foxglove WebSocket server with one channel per rfsas topic.

    Args:
        host: address to bind (loopback by default).
        port: TCP port (0: any free port; see :attr:`port`).
        name: server name shown in the app.

    Raises:
        MissingDependencyError: ``foxglove-sdk`` is not installed.
        ConfigError: the server cannot start (port in use, bad address).
    """

    def __init__(
        self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, name: str = "rfsas"
    ) -> None:
        fox = require("foxglove")
        self._context: Any = fox.Context()
        self._channels: dict[str, Any] = {}
        for topic in topics.ALL:
            schema = fox.Schema(
                name=topic.typename, encoding="ros2msg", data=msgdef(topic.typename).encode()
            )
            self._channels[topic.name] = fox.Channel(
                topic.name,
                schema=schema,
                message_encoding="cdr",
                context=self._context,
                metadata={"offered_qos_profiles": qos_yaml(topic)},
            )
        try:
            self._server: Any = fox.start_server(
                name=name, host=host, port=port, context=self._context
            )
        except Exception as err:  # the SDK raises its own error types
            raise ConfigError(f"foxglove server on {host}:{port}: cannot start: {err}") from err
        self.host = host
        self.messages = 0
        self._closed = False

    @property
    def port(self) -> int:
        """The TCP port the server listens on."""
        return int(self._server.port)

    @property
    def url(self) -> str:
        """The ``ws://`` address to open in Foxglove."""
        return f"ws://{self.host}:{self.port}"

    def write(self, topic: Topic, log_time_ns: int, data: bytes) -> None:
        """Send one CDR message to every client subscribed to ``topic``."""
        if self._closed:
            return
        self._channels[topic.name].log(data, log_time=int(log_time_ns))
        self.messages += 1

    def close(self, drain_s: float = 0.25) -> None:
        """Stop the server and close the channels; idempotent.

        Args:
            drain_s: seconds to wait first, so that messages still queued for the
                clients (the last step of a run) reach them before the sockets close.
        """
        if self._closed:
            return
        self._closed = True
        if drain_s > 0:
            time.sleep(drain_s)
        try:
            self._server.stop()
        finally:
            for channel in self._channels.values():
                channel.close()
