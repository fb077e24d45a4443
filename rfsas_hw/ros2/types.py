"""The ROS 2 message types rfsas speaks: the shipped ``.msg`` files plus the standard set.

The standard definitions (``std_msgs``, ``geometry_msgs``,
``visualization_msgs``, ``diagnostic_msgs``, ``tf2_msgs``, ``nav_msgs``) are
those of ROS 2 Jazzy as ``rosbags`` carries them; ``rfsas_msgs`` and
``radar_msgs`` come from ``msgs/<package>/msg/*.msg`` in this package, so
nothing needs a ROS installation. Messages are serialised to CDR, the bytes
that go into a bag, an MCAP file, a DDS sample or a Foxglove channel alike.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Any

from rfsas_hw.errors import ConfigError
from rfsas_hw.optional import require

MSGS_DIR = Path(__file__).resolve().parent / "msgs"
"""Root of the shipped definitions: ``<package>/msg/<Type>.msg``."""

RFSAS_MSGS_VERSION = 1
"""Value of the ``VERSION`` constant in every ``rfsas_msgs`` message of this release."""

DISTRO = "jazzy"
"""ROS 2 distribution whose standard message definitions are used."""


def shipped_definitions() -> dict[str, str]:
    """Every shipped ``.msg`` file as ``{"pkg/msg/Type": text}``, sorted by name."""
    out = {}
    for path in sorted(MSGS_DIR.glob("*/msg/*.msg")):
        out[f"{path.parent.parent.name}/msg/{path.stem}"] = path.read_text(encoding="utf-8")
    return out


@cache
def typestore() -> Any:
    """The ``rosbags`` typestore with the standard Jazzy types and the shipped ones.

    Raises:
        MissingDependencyError: ``rosbags`` is not installed.
        ConfigError: a shipped definition does not parse (a broken installation).
    """
    typesys = require("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for name, text in shipped_definitions().items():
        try:
            types.update(typesys.get_types_from_msg(text, name))
        except Exception as err:  # rosbags raises its own parse errors
            raise ConfigError(f"{MSGS_DIR / name}.msg: does not parse: {err}") from err
    store.register(types)
    return store


@cache
def msg_class(typename: str) -> Any:
    """The dataclass of ``typename`` (``pkg/msg/Type``) in :func:`typestore`.

    Raises:
        ConfigError: the type is not known.
    """
    try:
        return typestore().types[typename]
    except KeyError as err:
        raise ConfigError(f"unknown ROS 2 message type {typename!r}") from err


def serialize(message: Any, typename: str) -> bytes:
    """CDR bytes (little-endian, with the 4-byte encapsulation header) of ``message``."""
    return bytes(typestore().serialize_cdr(message, typename))


def deserialize(data: bytes, typename: str) -> Any:
    """The message object of CDR ``data``."""
    return typestore().deserialize_cdr(data, typename)


@cache
def msgdef(typename: str) -> str:
    """The ``ros2msg`` schema text of ``typename`` with every dependency appended
    (the form MCAP files and rosbag2 metadata carry)."""
    text, _ = typestore().generate_msgdef(typename, ros_version=2)
    return str(text)


@cache
def type_hash(typename: str) -> str:
    """The ``RIHS01_…`` type hash ROS 2 (Iron and later) uses to match types."""
    return str(typestore().hash_rihs01(typename))
