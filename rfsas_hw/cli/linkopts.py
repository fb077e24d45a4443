"""``--send``, ``--keys`` and ``--nonces``: options of the commands that run a sensor.

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

from rfsas_hw.apps.sensor import open_cue_publisher, open_nonce_inbox, open_publisher
from rfsas_hw.cli.options import keys_option
from rfsas_hw.link.cue_publisher import CuePublisher
from rfsas_hw.link.distribution import NonceInbox
from rfsas_hw.link.preauth import NonceSource
from rfsas_hw.link.publisher import Publisher
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, DEFAULT_GRACE_S
from rfsas_hw.records import Pose

F = TypeVar("F", bound=Callable[..., Any])


FALLBACK_KEY = "rfsas.fallback"
"""Where ``--fallback`` is kept in the click context (commands need no extra parameter)."""


SEND_CUES_KEY = "rfsas.send_cues"
"""Where ``--send-cues`` is kept in the click context."""


def _keep_fallback(ctx: click.Context, _param: click.Parameter, value: str | None) -> None:
    ctx.meta[FALLBACK_KEY] = value


def _keep_send_cues(ctx: click.Context, _param: click.Parameter, value: str | None) -> None:
    ctx.meta[SEND_CUES_KEY] = value


def send_options(func: F) -> F:
    """Add ``--send URL``, ``--fallback URL`` and ``--keys DIR`` to a click command."""
    func = click.option(
        "--send-cues",
        metavar="URL",
        expose_value=False,
        callback=_keep_send_cues,
        help="Also send signed cues for the bearings (channel, bearing, validity 2 s; one per "
        "emitter every 0.5 s) so that vehicles' sensors tune to the channel (needs --keys).",
    )(func)
    func = click.option(
        "--fallback",
        metavar="URL",
        expose_value=False,
        callback=_keep_fallback,
        help="Out-of-band path for --send (any URL --send takes): traffic moves there "
        "after repeated send errors on the primary, and back after 2 s without one.",
    )(func)
    func = keys_option(
        "Sensor key directory (rfsas keys new --role sensor) that signs what --send sends.",
        required=False,
    )(func)
    func = click.option(
        "--send",
        metavar="URL",
        multiple=True,
        callback=join_urls,
        help="Publish bearings as signed safety messages: udp://HOST:PORT (unicast or "
        "multicast), mqtt://HOST or mqtts://HOST?ca=…&cert=…&key=… (a broker; add "
        "origin=LAT,LON). Repeat to send on several at once.",
    )(func)
    return func


def join_urls(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]) -> str | None:
    """Click callback of a repeatable URL option: the URLs separated by spaces, or None.

    URLs hold no spaces, so commands keep one ``str | None`` value and
    :func:`split_urls` gives the list back.
    """
    return " ".join(value) if value else None


def split_urls(value: str) -> list[str]:
    """The URLs :func:`join_urls` joined."""
    return value.split()


def kept_link_options() -> tuple[str | None, str | None]:
    """``--fallback`` and ``--send-cues`` of the running command (kept in the click
    context by :func:`send_options`), or Nones outside a command."""
    ctx = click.get_current_context(silent=True)
    if ctx is None:
        return None, None
    return ctx.meta.get(FALLBACK_KEY), ctx.meta.get(SEND_CUES_KEY)


def make_publisher(
    send: str | None,
    keys_dir: Path | None,
    pose: Pose,
    epoch_s: float = DEFAULT_EPOCH_S,
    preauth: NonceSource | None = None,
) -> Publisher | None:
    """The publisher ``--send``/``--keys``/``--fallback`` ask for, or None without
    ``--send`` (see :func:`rfsas_hw.apps.sensor.open_publisher`); ``send`` may hold
    several URLs (see :func:`join_urls`).

    Raises:
        ConfigError: ``--send`` without ``--keys``, or ``--fallback`` without ``--send``.
        KeyStoreError: the key directory is not a usable sensor identity.
        LinkError: bad URL or socket failure.
    """
    fallback, _ = kept_link_options()
    urls = split_urls(send) if send is not None else []
    return open_publisher(urls, keys_dir, pose, epoch_s, preauth, fallback)


def make_cue_publisher(
    keys_dir: Path | None, pose: Pose, epoch_s: float = DEFAULT_EPOCH_S
) -> CuePublisher | None:
    """The cue publisher ``--send-cues URL`` asks for (signing with ``--keys``), or None.

    Raises:
        ConfigError: ``--send-cues`` without ``--keys``.
        KeyStoreError: the key directory is not a usable sensor identity.
        LinkError: bad URL or socket failure.
    """
    _, url = kept_link_options()
    return open_cue_publisher(url, keys_dir, pose, epoch_s)


NONCES_HELP = (
    "Hash MACs with the deployment's epoch nonces, received here from the nonce "
    "authority (needs --keys; default: a random key for this run)."
)


def nonce_inbox(
    nonces: str,
    keys_dir: Path | None,
    epoch_s: float = DEFAULT_EPOCH_S,
    grace_s: float = DEFAULT_GRACE_S,
    wait_s: float = 10.0,
) -> NonceInbox:
    """The nonce provider ``--nonces udp://HOST:PORT --keys DIR`` asks for (see
    :func:`rfsas_hw.apps.sensor.open_nonce_inbox`).

    Raises:
        ConfigError: ``--nonces`` without ``--keys``.
        KeyStoreError: the key directory has no enrolled authority or no usable key.
        LinkError: bad URL or socket failure.
    """
    return open_nonce_inbox(nonces, keys_dir, epoch_s, grace_s, wait_s)
