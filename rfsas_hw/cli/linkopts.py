"""``--send`` and ``--keys``: the options of every command that publishes signed bearings.

Usage in a command::

    @click.command()
    @send_options
    def replay(..., send: str | None, keys_dir: Path | None) -> None:
        publisher = make_publisher(send, keys_dir, pose, epoch_s)
        if publisher is not None:
            fanout.add(publisher)
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click

from rfsas_hw.errors import ConfigError
from rfsas_hw.link.publisher import Publisher
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S
from rfsas_hw.records import Pose

F = TypeVar("F", bound=Callable[..., Any])


def send_options(func: F) -> F:
    """Add ``--send URL`` and ``--keys DIR`` to a click command."""
    func = click.option(
        "--keys",
        "keys_dir",
        type=click.Path(file_okay=False, path_type=Path),
        help="Sensor key directory (rfsas keys new --role sensor) that signs what --send sends.",
    )(func)
    func = click.option(
        "--send",
        metavar="udp://HOST:PORT",
        help="Publish bearings as signed safety messages (unicast or multicast UDP).",
    )(func)
    return func


def make_publisher(
    send: str | None,
    keys_dir: Path | None,
    pose: Pose,
    epoch_s: float = DEFAULT_EPOCH_S,
) -> Publisher | None:
    """The publisher ``--send``/``--keys`` ask for, or None without ``--send``.

    Raises:
        ConfigError: ``--send`` without ``--keys``.
        KeyStoreError: the key directory is not a usable sensor identity.
        LinkError: bad URL or socket failure.
    """
    if send is None:
        return None
    if keys_dir is None:
        raise ConfigError("--send needs --keys DIR: messages are signed with the sensor's key")
    return Publisher.from_keys(send, keys_dir, pose, epoch_s=epoch_s)
