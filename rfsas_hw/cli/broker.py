"""``rfsas broker config``: certificates, mosquitto.conf and ACL from the key store."""

from __future__ import annotations

from pathlib import Path

import click

from rfsas_hw.cli.options import keys_option, out_option
from rfsas_hw.fleet.broker import DEFAULT_PORT, write_broker_config


@click.group()
def broker() -> None:
    """The MQTT broker of a city-scale deployment (see docs/fleet.md)."""


@broker.command("config")
@keys_option("Key directory whose trust/ enrols everyone (usually the nonce authority's).")
@out_option(
    "Output directory (the CA and certificates already in it are kept).",
    kind="dir",
    required=True,
)
@click.option(
    "--host",
    default="localhost",
    show_default=True,
    help="Broker address clients connect to (an IP address or DNS name); the listener "
    "binds it when it is an IP address or localhost, else every address.",
)
@click.option(
    "--port",
    type=click.IntRange(0, 65535),
    default=DEFAULT_PORT,
    show_default=True,
    help="TLS port.",
)
@click.option(
    "--vehicle", "vehicles", multiple=True, metavar="ID", help="Admit a vehicle (repeatable)."
)
@click.option(
    "--gateway",
    "gateways",
    multiple=True,
    metavar="ID",
    help="Admit a vehicle gateway: reads every vehicle's advisories, for the vehicles "
    "behind it (repeatable; rfsas city run's is 'vehicles').",
)
@click.option(
    "--run-as",
    default="mosquitto",
    show_default=True,
    help="User mosquitto drops to when started as root (it must read the broker files).",
)
@click.option(
    "--days",
    type=click.IntRange(1, 3650),
    default=365,
    show_default=True,
    help="Validity of the certificates issued now, days (a new CA gets at least 3650).",
)
def config(
    keys_dir: Path,
    out: Path,
    host: str,
    port: int,
    vehicles: tuple[str, ...],
    gateways: tuple[str, ...],
    run_as: str,
    days: int,
) -> None:
    """Write a CA, one client certificate per identity (named by its rfsas id), the
    broker's certificate, a mosquitto.conf with mutual TLS, use_identity_as_username
    and set_tcp_nodelay, and an ACL that lets each sensor write only its own
    bearing topics and read only its own nonce topic."""
    files = write_broker_config(
        keys_dir,
        out,
        host=host,
        port=port,
        vehicles=vehicles,
        gateways=gateways,
        run_as=run_as,
        days=days,
    )
    for ident in sorted(files.identities, key=lambda i: (i.role, i.id)):
        state = "new certificate" if ident.id in files.issued else "kept"
        if ident.id in files.replaced:
            state = "new certificate (the one found was not this CA's for it)"
        click.echo(f"{ident.role:9} {ident.id:32} {state}")
    click.echo(f"wrote {files.conf} and {files.acl}; start with: mosquitto -c {files.conf}")
    click.echo(f"keep {files.root / 'ca' / 'ca.key'} offline: it admits new clients")
