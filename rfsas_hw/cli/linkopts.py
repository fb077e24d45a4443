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

import weakref
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click

from rfsas_hw.errors import ConfigError
from rfsas_hw.fleet.certname import check_certificate_names
from rfsas_hw.link.cue_publisher import CuePublisher
from rfsas_hw.link.distribution import NonceInbox
from rfsas_hw.link.fallback import FallbackSender
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.preauth import NonceSource
from rfsas_hw.link.publisher import Publisher
from rfsas_hw.link.transport import open_transport, open_transports
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, DEFAULT_GRACE_S, EpochSchedule
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
    func = click.option(
        "--keys",
        "keys_dir",
        type=click.Path(file_okay=False, path_type=Path),
        help="Sensor key directory (rfsas keys new --role sensor) that signs what --send sends.",
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


def make_publisher(
    send: str | None,
    keys_dir: Path | None,
    pose: Pose,
    epoch_s: float = DEFAULT_EPOCH_S,
    preauth: NonceSource | None = None,
) -> Publisher | None:
    """The publisher ``--send``/``--keys`` ask for, or None without ``--send``.
    ``send`` may hold several URLs (see :func:`join_urls`); with the deployment's
    epoch nonces in ``preauth`` it sends version-2 (pre-authenticated) messages.

    With ``--fallback URL`` the publisher sends through a
    :class:`~rfsas_hw.link.fallback.FallbackSender` (``--send`` is its primary).

    Raises:
        ConfigError: ``--send`` without ``--keys``, or ``--fallback`` without ``--send``.
        KeyStoreError: the key directory is not a usable sensor identity.
        LinkError: bad URL or socket failure.
    """
    ctx = click.get_current_context(silent=True)
    fallback = ctx.meta.get(FALLBACK_KEY) if ctx is not None else None
    if send is None:
        if fallback is not None:
            raise ConfigError("--fallback is the out-of-band path of --send: give --send too")
        return None
    if keys_dir is None:
        raise ConfigError("--send needs --keys DIR: messages are signed with the sensor's key")
    ident = KeyStore.open(keys_dir).id
    check_certificate_names(split_urls(send), ident, "--send")
    check_certificate_names([fallback] if fallback else [], ident, "--fallback")
    if fallback is None:
        return Publisher.from_keys(
            split_urls(send), keys_dir, pose, epoch_s=epoch_s, preauth=preauth
        )
    signer = KeyStore.open(keys_dir).signer()
    primary = open_transports(split_urls(send), "send")
    try:
        secondary = open_transport(fallback, "send")
    except BaseException:
        primary.close()
        raise
    return Publisher(
        signer, FallbackSender(primary, secondary), pose, epoch_s=epoch_s, preauth=preauth
    )


def make_cue_publisher(
    keys_dir: Path | None, pose: Pose, epoch_s: float = DEFAULT_EPOCH_S
) -> CuePublisher | None:
    """The cue publisher ``--send-cues URL`` asks for (signing with ``--keys``), or None.

    Raises:
        ConfigError: ``--send-cues`` without ``--keys``.
        KeyStoreError: the key directory is not a usable sensor identity.
        LinkError: bad URL or socket failure.
    """
    ctx = click.get_current_context(silent=True)
    url = ctx.meta.get(SEND_CUES_KEY) if ctx is not None else None
    if url is None:
        return None
    if keys_dir is None:
        raise ConfigError("--send-cues needs --keys DIR: cues are signed with the sensor's key")
    store = KeyStore.open(keys_dir)
    check_certificate_names([url], store.id, "--send-cues")
    signer = store.signer()
    return CuePublisher(signer, open_transport(url, "send"), pose, epoch_s=epoch_s)


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
    """The nonce provider ``--nonces udp://HOST:PORT --keys DIR`` asks for: it listens for
    the authority's envelopes and waits up to ``wait_s`` for a missing epoch's nonce.

    Raises:
        ConfigError: ``--nonces`` without ``--keys``.
        KeyStoreError: the key directory has no enrolled authority or no usable key.
        LinkError: bad URL or socket failure.
    """
    if keys_dir is None:
        raise ConfigError("--nonces needs --keys DIR: envelopes are sealed to the sensor's key")
    keys = KeyStore.open(keys_dir)
    check_certificate_names([nonces], keys.id, "--nonces")
    store = keys.nonce_store(EpochSchedule(epoch_s, grace_s))
    inbox = NonceInbox(store, open_transport(nonces, "recv"), wait_s=wait_s)
    # the command keeps the inbox for its whole run; close the socket when it goes
    weakref.finalize(inbox, inbox.transport.close)
    return inbox
