"""``rfsas advisories``: what a vehicle hears from the backends — verified advisories."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import click

from rfsas_hw.cli.linkopts import join_urls, split_urls
from rfsas_hw.cli.options import duration_option, json_option
from rfsas_hw.errors import ConfigError
from rfsas_hw.fleet.advisory import AdvisoryItem, AdvisoryReceiver, check_advisory_urls
from rfsas_hw.link.keys import TrustDir
from rfsas_hw.link.transport import open_transports


def _number(value: float) -> float | None:
    return round(value, 3) if math.isfinite(value) else None


def _line(item: AdvisoryItem, backend: str) -> dict[str, object]:
    return {
        "backend": backend,
        "emitter": item.emitter,
        "t_ns": item.t_ns,
        "advisory": item.advisory,
        "x_m": _number(item.x_m),
        "y_m": _number(item.y_m),
        "p_collision": _number(item.p_collision),
        "risk": _number(item.risk),
        "fix_ok": item.fix_ok,
        "link_alarm": item.link_alarm,
    }


@click.command("advisories")
@click.option(
    "--listen",
    required=True,
    multiple=True,
    callback=join_urls,
    metavar="URL",
    help="Where advisories arrive: a broker URL with the vehicle's certificate and "
    "sub=rfsas/v1/vehicle/ID/advisory (or advisories=TILES), or udp://HOST:PORT; repeatable.",
)
@click.option(
    "--trust",
    "trust_dir",
    type=click.Path(file_okay=False, exists=True, path_type=Path),
    required=True,
    help="Directory of the enrolled backends' key cards (ID.yaml).",
)
@click.option("--vehicle-id", default="", metavar="ID", help="Refuse advisories for others.")
@duration_option("Stop after this many seconds (default: Ctrl-C).")
@json_option("One JSON object per assessment.")
def advisories(
    listen: str,
    trust_dir: Path,
    vehicle_id: str,
    duration: float | None,
    as_json: bool,
) -> None:
    """Verify the backends' signed advisories and print each assessment (emitter,
    advisory, position, risk); at the end, the counts by rejection reason."""
    trust = TrustDir(trust_dir)
    if not any(trust.backend_key(card.id) for card in trust):
        raise ConfigError(f"{trust_dir}: no backend card with a signing key")
    urls = split_urls(listen)
    check_advisory_urls(urls)
    transport = open_transports(urls, "recv")
    rx = AdvisoryReceiver(trust, transport, vehicle_id=vehicle_id)
    stop = None if duration is None else time.monotonic() + duration
    try:
        while stop is None or time.monotonic() < stop:
            left = 0.2 if stop is None else max(0.0, min(0.2, stop - time.monotonic()))
            for msg in rx.receive(timeout=left):
                for item in msg.items:
                    if as_json:
                        click.echo(json.dumps(_line(item, msg.sender_id), sort_keys=True))
                    else:
                        pos = (
                            f"{item.x_m:7.1f}, {item.y_m:7.1f} m"
                            if math.isfinite(item.x_m)
                            else "not located"
                        )
                        click.echo(
                            f"{msg.sender_id:12} {item.emitter} {item.advisory:8} {pos}  "
                            f"risk {item.risk:.2e}"
                        )
    except KeyboardInterrupt:
        pass
    finally:
        transport.close()
    stats = {"datagrams": rx.stats.datagrams, "verified": rx.stats.verified}
    stats.update({f"rejected.{k}": v for k, v in sorted(rx.stats.rejected.items())})
    if as_json:
        click.echo(json.dumps({"stats": stats}, sort_keys=True))
    else:
        click.echo(", ".join(f"{k} {v}" for k, v in stats.items()), err=True)
