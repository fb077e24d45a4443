"""``rfsas v2x decode``: print Collective Perception Messages as JSON, ours or any station's.

Also the ``cpm`` format of ``rfsas export`` (:func:`export_cpm`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import click

from rfsas_hw.cli.exitcodes import FAILED
from rfsas_hw.cli.options import duration_option
from rfsas_hw.errors import ConfigError, CpmFormatError


def _line(data: dict[str, Any]) -> str:
    return json.dumps(data, separators=(",", ":"))


def _decode_file(path: Path) -> tuple[int, int]:
    """Print every CPM of a file; (decoded, bad)."""
    from rfsas_hw.v2x.codec import decode_cpm_tree
    from rfsas_hw.v2x.geonet import read_cpm_file

    contents = read_cpm_file(path)
    if not contents.capture:  # one message: a broken one is the command's error (exit 2)
        tree = decode_cpm_tree(contents.cpms[0][2])
        click.echo(_line({"source": str(path), "cpm": tree}))
        return 1, 0
    for problem in contents.problems:
        click.echo(f"skipped: {problem}", err=True)
    decoded, bad = 0, len(contents.problems)
    for frame_no, t_ns, cpm in contents.cpms:
        try:
            tree = decode_cpm_tree(cpm)
        except CpmFormatError as err:
            click.echo(f"skipped: {path}: frame {frame_no}: {err}", err=True)
            bad += 1
            continue
        click.echo(_line({"source": str(path), "frame": frame_no, "t_ns": t_ns, "cpm": tree}))
        decoded += 1
    return decoded, bad


@click.group("v2x")
def v2x() -> None:
    """ETSI Collective Perception Messages (CPM v2, TS 103 324 v2.1.1): see docs/v2x.md."""


@v2x.command("decode")
@click.argument("source")
@click.option(
    "--allow",
    multiple=True,
    metavar="NETWORK",
    help="udp: senders accepted (an address or a network; repeat) [default: loopback].",
)
@click.option(
    "--count",
    type=click.IntRange(min=1),
    help="udp/mqtt: stop after this many datagrams.",
)
@duration_option("udp/mqtt: stop after this many seconds [default: Ctrl-C].")
def decode(source: str, allow: tuple[str, ...], count: int | None, duration: float | None) -> None:
    """Print the CPMs in SOURCE as JSON lines.

    SOURCE is a file (a pcap/pcapng of GeoNetworking frames, or one CPM, bare or
    behind BTP-B/GeoNetworking headers), udp://HOST:PORT, or mqtt(s)://HOST[:PORT]/TOPIC.
    CPMs from any station are read; a datagram that is not one is named on stderr.

    \b
    rfsas v2x decode run.pcap
    rfsas v2x decode udp://0.0.0.0:2009 --allow 10.0.0.0/8
    rfsas v2x decode mqtt://broker.local/its/cpm --count 10
    """
    if "://" not in source:
        decoded, bad = _decode_file(Path(source))
        click.echo(f"decoded {decoded} CPM(s), skipped {bad}", err=True)
        if decoded == 0:
            raise SystemExit(FAILED)
        return
    from rfsas_hw.v2x.listen import CpmListener

    listener = CpmListener(source, allow) if allow else CpmListener(source)
    click.echo(f"listening on {source}", err=True)
    end = None if duration is None else time.monotonic() + duration
    seen = 0
    try:
        while count is None or seen < count:
            left = None if end is None else end - time.monotonic()
            if left is not None and left <= 0:
                break
            got = listener.receive(timeout=left if left is not None else 1.0)
            if got is None:
                continue
            seen += 1
            if got.cpm is None:
                click.echo(f"skipped: {got.error}", err=True)
                continue
            # one line per message as it arrives, also into a pipe
            print(_line({"source": got.sender, "t_ns": got.t_ns, "cpm": got.cpm}), flush=True)
    except KeyboardInterrupt:
        click.echo("stopped", err=True)
    finally:
        listener.close()
    stats = listener.stats
    click.echo(
        f"received {stats['received']}, decoded {stats['decoded']}, not a CPM {stats['bad']}, "
        f"refused senders {stats['refused_sender']}",
        err=True,
    )


def export_cpm(runs: tuple[Path, ...], out: Path, fmt: str, opts: dict[str, Any]) -> list[str]:
    """``rfsas export --to cpm``: one run log as a pcap of CPM frames; the lines to print.

    Raises:
        ConfigError: more than one run, or a bad origin.
        ExportError: unreadable log, no origin, unwritable output.
    """
    from rfsas_hw.backend.site import parse_origin
    from rfsas_hw.v2x.export import export_cpm_pcap

    if len(runs) != 1:
        raise ConfigError(f"--to {fmt} exports one run log at a time, got {len(runs)}")
    origin = parse_origin(opts["origin"]) if opts.get("origin") else None
    result = export_cpm_pcap(runs[0], out, origin=origin)
    lines = [
        f"wrote {result.path}: {result.messages} CPMs with {result.objects} perceived objects "
        f"from {result.steps} backend steps"
    ]
    for reason, n in sorted(result.run.skipped.items()):
        lines.append(f"skipped {n} line(s): {reason}")
    lines += [f"  {message}" for message in result.run.errors[:5]]
    return lines
