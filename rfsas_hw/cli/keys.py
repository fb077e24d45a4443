"""``rfsas keys``: create identities, show and export public cards, enroll and revoke."""

from __future__ import annotations

from pathlib import Path

import click

from rfsas_hw.cli.options import out_option
from rfsas_hw.errors import KeyStoreError
from rfsas_hw.link.keys import CARD_FILE, ROLES, KeyCard, KeyStore


@click.group()
def keys() -> None:
    """Key directories for sensors, backends and the nonce authority.

    A typical deployment: every party runs `keys new`; the authority enrolls every
    sensor and backend card, each sensor and backend enrolls the authority's card,
    and each backend enrolls the sensors it listens to.
    """


@keys.command("new")
@click.option("--role", type=click.Choice(ROLES), required=True, help="What this identity does.")
@click.option("--id", "ident", help="Identity id, 1-32 of A-Z a-z 0-9 . _ - (default: DIR name).")
@out_option(
    "Key directory to create (existing key files are never overwritten).",
    dest="directory",
    kind="dir",
    required=True,
)
def new(role: str, ident: str | None, directory: Path) -> None:
    """Generate the private keys and public card of a new identity."""
    store = KeyStore.create(directory, role, ident)
    click.echo(f"created {store.role} {store.id!r} in {directory}")
    click.echo(f"  public card: {directory / CARD_FILE} (give this to the other parties)")
    click.echo(f"  fingerprint: {store.card.fingerprint}")


@keys.command("show")
@click.argument("directory", type=click.Path(file_okay=False, path_type=Path))
def show(directory: Path) -> None:
    """Show an identity, its fingerprint and the cards it trusts."""
    store = KeyStore.open(directory)
    card = store.card
    click.echo(f"id:          {card.id}")
    click.echo(f"role:        {card.role}")
    click.echo(f"fingerprint: {card.fingerprint}")
    click.echo(f"signs:       {'yes (ECDSA P-256)' if card.sign_public else 'no'}")
    if len(store.trust) == 0:
        click.echo("trusts:      nobody yet (rfsas keys enroll)")
        return
    click.echo("trusts:")
    for other in store.trust:
        click.echo(f"  {other.id:<32} {other.role:<9} {other.fingerprint}")


@keys.command("export")
@click.argument("directory", type=click.Path(file_okay=False, path_type=Path))
@out_option(
    "Write the card here (refuses to overwrite); default: standard output.",
    dest="output",
    kind="new_file",
)
def export(directory: Path, output: Path | None) -> None:
    """Export the public card of an identity (no private key ever leaves DIR)."""
    text = KeyStore.open(directory).card.to_yaml()
    if output is None:
        click.echo(text, nl=False)
        return
    try:
        with output.open("x", encoding="utf-8") as fh:
            fh.write(text)
    except FileExistsError as err:
        raise KeyStoreError(f"{output}: already exists; refusing to overwrite") from err
    except OSError as err:
        raise KeyStoreError(f"{output}: cannot write: {err.strerror or err}") from err


@keys.command("enroll")
@click.argument("directory", type=click.Path(file_okay=False, path_type=Path))
@click.argument("cards", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--replace", is_flag=True, help="Replace an enrolled card with different keys.")
def enroll(directory: Path, cards: tuple[Path, ...], replace: bool) -> None:
    """Trust the public CARDS (card files or key directories) in key directory DIRECTORY."""
    store = KeyStore.open(directory)
    for path in cards:
        card = KeyCard.load(path)
        if card.id == store.id:
            raise KeyStoreError(f"{path}: is this identity's own card ({card.id!r})")
        dest = store.trust.enroll(card, replace=replace)
        click.echo(f"enrolled {card.role} {card.id!r} ({card.fingerprint}) -> {dest}")


@keys.command("revoke")
@click.argument("directory", type=click.Path(file_okay=False, path_type=Path))
@click.argument("ident")
def revoke(directory: Path, ident: str) -> None:
    """Stop trusting IDENT in key directory DIRECTORY."""
    KeyStore.open(directory).trust.revoke(ident)
    click.echo(f"revoked {ident!r}")
