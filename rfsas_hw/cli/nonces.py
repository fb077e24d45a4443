"""``rfsas nonces``: run the nonce authority, or check that a receiver gets its nonces."""

from __future__ import annotations

import time
from pathlib import Path

import click

from rfsas_hw.cli.exitcodes import WorkFailed
from rfsas_hw.cli.options import duration_option, keys_option, out_option
from rfsas_hw.errors import ConfigError
from rfsas_hw.fleet.certname import check_certificate_names
from rfsas_hw.link.distribution import NonceDistributor, NonceInbox
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.transport import Transport, open_transport
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, DEFAULT_GRACE_S, EpochSchedule
from rfsas_hw.privacy.hashing import write_secret

KEYS_HELP = "Key directory (rfsas keys new); its trust/ holds the enrolled cards."


epoch_option = click.option(
    "--epoch",
    "epoch_s",
    type=click.FloatRange(min=1.0),
    default=DEFAULT_EPOCH_S,
    show_default=True,
    help="Epoch length, seconds.",
)


def _schedule(epoch_s: float, grace_s: float) -> EpochSchedule:
    try:
        return EpochSchedule(epoch_s, grace_s)
    except ValueError as err:
        raise ConfigError(f"--epoch/--grace: {err}") from err


@click.group()
def nonces() -> None:
    """Epoch nonces: the authority hands them to enrolled sensors and backends."""


@nonces.command("serve")
@keys_option(KEYS_HELP)
@click.option(
    "--to",
    "targets",
    multiple=True,
    metavar="ID=udp://HOST:PORT",
    required=True,
    help="Where an enrolled receiver listens (repeat for each).",
)
@epoch_option
@click.option(
    "--grace",
    "grace_s",
    type=click.FloatRange(min=0.0),
    default=DEFAULT_GRACE_S,
    show_default=True,
    help="Receivers' grace period at a boundary, seconds.",
)
@click.option(
    "--resend",
    "resend_s",
    type=click.FloatRange(min=0, min_open=True),
    default=5.0,
    show_default=True,
    help="Send each envelope again after this many seconds.",
)
@duration_option("Stop after this many seconds (default: Ctrl-C).")
def serve(
    keys_dir: Path,
    targets: tuple[str, ...],
    epoch_s: float,
    grace_s: float,
    resend_s: float,
    duration: float | None,
) -> None:
    """Draw a fresh nonce per epoch and send it, ahead of time, to every enrolled receiver.

    The nonces are kept in the key directory (nonces.state): restarted on the same
    directory, the authority hands out the same nonces. Enrolments and revocations
    in trust/ take effect within 2 s, without a restart.
    """
    store = KeyStore.open(keys_dir)
    authority = store.nonce_authority(_schedule(epoch_s, grace_s))
    destinations: dict[str, Transport] = {}
    for target in targets:
        rid, sep, url = target.partition("=")
        if not sep or not rid or not url:
            raise ConfigError(f"--to {target!r}: expected ID=udp://HOST:PORT")
        if rid not in authority.receivers:
            raise ConfigError(
                f"--to {rid}: not enrolled with authority {authority.authority_id!r} "
                f"(rfsas keys enroll {keys_dir} CARD)"
            )
        check_certificate_names([url], authority.authority_id, f"--to {rid}")
        destinations[rid] = open_transport(url, "send")
    dist = NonceDistributor(authority, destinations, resend_s=resend_s)
    click.echo(
        f"authority {authority.authority_id!r}: {len(destinations)} of "
        f"{len(authority.receivers)} enrolled receivers reachable; epochs of {epoch_s:g} s"
    )
    stop = None if duration is None else time.monotonic() + duration
    current = None
    try:
        while stop is None or time.monotonic() < stop:
            if store.trust.refresh():
                authority.enroll_only(store.trust.receivers())
            dist.tick()
            epoch = authority.schedule.epoch_of(time.time_ns())
            if epoch != current:
                current = epoch
                click.echo(f"epoch {epoch}: nonces of epochs {epoch} and {epoch + 1} handed out")
            time.sleep(0.2 if stop is None else min(0.2, max(0.0, stop - time.monotonic())))
    except KeyboardInterrupt:
        pass
    finally:
        dist.close()
    sent = ", ".join(f"{rid} {n}" for rid, n in sorted(dist.sent.items())) or "none"
    errors = sum(dist.errors.values())
    # a broker that refuses a publish (not authorised) says so only in its acknowledgement
    refused = sum(getattr(getattr(t, "stats", None), "refused", 0) for t in destinations.values())
    click.echo(f"envelopes sent: {sent}; send errors: {errors}; refused by the broker: {refused}")
    if refused:
        raise WorkFailed(f"the broker refused {refused} envelope(s) (not authorised?)")
    # an outage ridden out is counted and logged, not a failed run: only a receiver
    # still unreachable at the end is
    if dist.failing:
        failed = ", ".join(f"{rid} ({dist.errors[rid]} errors)" for rid in sorted(dist.failing))
        raise WorkFailed(f"envelopes could not be sent at the end: {failed}")
    if not sum(dist.sent.values()):
        raise WorkFailed("no envelope was sent (no enrolled receiver has an address)")


@nonces.command("listen")
@keys_option(KEYS_HELP)
@click.option(
    "--listen",
    "url",
    required=True,
    metavar="udp://HOST:PORT",
    help="Where envelopes for this receiver arrive.",
)
@epoch_option
@click.option(
    "--grace",
    "grace_s",
    type=click.FloatRange(min=0.0),
    default=DEFAULT_GRACE_S,
    show_default=True,
    help="Grace period at a boundary, seconds.",
)
@duration_option("How long to listen, seconds.", default=10.0)
def listen(keys_dir: Path, url: str, epoch_s: float, grace_s: float, duration: float) -> None:
    """Check that this sensor or backend receives its nonces (prints epochs, never nonces)."""
    keys = KeyStore.open(keys_dir)
    check_certificate_names([url], keys.id, "URL")
    store = keys.nonce_store(_schedule(epoch_s, grace_s))
    inbox = NonceInbox(store, open_transport(url, "recv"))
    stop = time.monotonic() + duration
    shown: tuple[int, ...] = ()
    try:
        while time.monotonic() < stop:
            inbox.poll(timeout=min(0.2, max(0.0, stop - time.monotonic())))
            if store.epochs != shown:
                shown = store.epochs
                click.echo(f"holding nonces of epochs {', '.join(map(str, shown))}")
    except KeyboardInterrupt:
        pass
    finally:
        inbox.close()
    click.echo(f"envelopes accepted {inbox.accepted}, refused {inbox.rejected}")
    if inbox.accepted == 0:
        raise WorkFailed(f"{url}: no nonce envelope for {store.receiver_id!r} arrived")


@nonces.command("secret")
@out_option(
    "File to create (mode 0600; an existing file is never overwritten).",
    dest="output",
    required=True,
    kind="new_file",
)
def secret(output: Path) -> None:
    """Create a shared nonce secret for sensors without a nonce authority.

    Sensors given the same file (`--nonce-secret FILE` on replay and live)
    derive the same emitter ids, so a backend can associate their bearings.
    Whoever holds the file can link ids across every epoch: prefer
    `rfsas nonces serve` for a deployment.
    """
    write_secret(output)
    click.echo(f"wrote a 32-byte nonce secret to {output} (mode 0600)")
