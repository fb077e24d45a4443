"""Entry point of the ``rfsas`` command.

Subcommands live in their own modules and are added to :data:`COMMANDS`.
Any :class:`~rfsas_hw.errors.RfsasError` becomes one line on stderr and exit
code 2 (an :class:`~rfsas_hw.errors.OutputError`, a failed write, exit code 1);
a traceback means a bug. Every command's output options follow
:mod:`rfsas_hw.cli.outopts`. Exit codes: :mod:`rfsas_hw.cli.exitcodes`.
SIGTERM ends a command the way Ctrl-C does (outputs and summary written).
"""

from __future__ import annotations

import importlib
import logging
import math
import signal
import sys
from collections.abc import Sequence
from types import FrameType
from typing import SupportsFloat, SupportsIndex

import click

from rfsas_hw import __version__
from rfsas_hw.cli.exitcodes import BAD_INPUT, EPILOG, FAILED, INTERRUPTED
from rfsas_hw.cli.outopts import guard_outputs
from rfsas_hw.errors import OutputError, RfsasError
from rfsas_hw.runner import Terminated

EXIT_BAD_INPUT = BAD_INPUT

# "module:attribute" of every subcommand, imported when the CLI starts.
COMMANDS: list[str] = [
    "rfsas_hw.cli.sim:sim",
    "rfsas_hw.cli.sumo:sumo",
    "rfsas_hw.cli.city:city",
    "rfsas_hw.cli.ncap:ncap",
    "rfsas_hw.cli.plan:plan",
    "rfsas_hw.cli.demo:demo",
    "rfsas_hw.cli.calibrate:calibrate",
    "rfsas_hw.cli.replay:replay",
    "rfsas_hw.cli.live:live",
    "rfsas_hw.cli.keys:keys",
    "rfsas_hw.cli.nonces:nonces",
    "rfsas_hw.cli.link:link",
    "rfsas_hw.cli.backend:backend",
    "rfsas_hw.cli.broker:broker",
    "rfsas_hw.cli.advisories:advisories",
    "rfsas_hw.cli.export:export",
    "rfsas_hw.cli.board:board",
    "rfsas_hw.cli.aoa:aoa",
    "rfsas_hw.cli.v2x:v2x",
]


@click.group(context_settings={"help_option_names": ["-h", "--help"]}, epilog=EPILOG)
@click.version_option(__version__, prog_name="rfsas")
@click.option("-v", "--verbose", count=True, help="More log output (repeat for debug).")
def cli(verbose: int) -> None:
    """RF situational awareness: monopulse DF from Wi-Fi/BLE frames to collision risk."""
    level = logging.WARNING - 10 * min(verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")


def _load_commands() -> None:
    for path in COMMANDS:
        module_name, _, attr = path.partition(":")
        command = getattr(importlib.import_module(module_name), attr)
        _add_epilog(command)
        guard_outputs(command)
        cli.add_command(command)


class FiniteFloat(click.types.FloatParamType):
    """A float option that refuses ``nan`` and ``inf`` (click's float takes both, and a NaN
    noise floor or speed silently poisons every result)."""

    def convert(
        self,
        value: SupportsFloat | SupportsIndex,
        param: click.Parameter | None,
        ctx: click.Context | None,
    ) -> float:
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


FINITE_FLOAT = FiniteFloat()


def _add_epilog(command: click.Command) -> None:
    """Every command's ``--help`` ends with the exit codes; every plain float option is
    finite."""
    if not command.epilog:
        command.epilog = EPILOG
    for param in command.params:
        if param.type is click.FLOAT:
            param.type = FINITE_FLOAT
    if isinstance(command, click.Group):
        for sub in command.commands.values():
            _add_epilog(sub)


def _terminate(signum: int, frame: FrameType | None) -> None:
    raise Terminated


def sigterm_as_interrupt() -> None:
    """From now on SIGTERM raises :class:`~rfsas_hw.runner.Terminated` (a
    KeyboardInterrupt) in the main thread: a service manager's stop ends a run
    as Ctrl-C does, with outputs flushed and the summary written."""
    signal.signal(signal.SIGTERM, _terminate)


def main(argv: Sequence[str] | None = None) -> None:
    """Run the CLI; turn library errors into one clear line and exit code 2 (1 for a
    failed write)."""
    _load_commands()
    sigterm_as_interrupt()
    try:
        cli.main(args=list(argv) if argv is not None else None, standalone_mode=False)
    except OutputError as err:
        click.echo(f"failed: {err}", err=True)
        sys.exit(FAILED)
    except RfsasError as err:
        click.echo(f"error: {err}", err=True)
        sys.exit(EXIT_BAD_INPUT)
    except (click.exceptions.Abort, KeyboardInterrupt):
        click.echo("aborted", err=True)
        sys.exit(INTERRUPTED)
    except click.ClickException as err:
        err.show()
        sys.exit(EXIT_BAD_INPUT if isinstance(err, click.UsageError) else err.exit_code)
    except click.exceptions.Exit as err:
        sys.exit(err.exit_code)


if __name__ == "__main__":
    main()
