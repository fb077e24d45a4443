"""Options that many commands share, declared once: one name and one meaning each.

- :func:`out_option`: ``-o/--out PATH``, where a command writes its result
  (``--output``, the name some commands used to take, still works but is not shown).
- :func:`duration_option`: ``--duration SECONDS``, how long a command runs.
- :func:`json_option`: ``--json``, one JSON object instead of a table.
- :func:`keys_option`: ``--keys DIR``, the command's key directory.
- :func:`runner_options`: ``--workers N`` and ``--scheduler ADDRESS``, where sweeps run.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

import click

from rfsas_hw.cli.outopts import OutputKind, OutputPath
from rfsas_hw.errors import ConfigError

F = TypeVar("F", bound=Callable[..., Any])


class AliasedOption(click.Option):
    """An option some of whose names are accepted but not shown in ``--help``
    (old names kept so that scripts keep working)."""

    def __init__(
        self, param_decls: Sequence[str], *, hidden_aliases: Sequence[str] = (), **attrs: Any
    ) -> None:
        super().__init__(list(param_decls), **attrs)
        self.hidden_aliases = tuple(hidden_aliases)

    def get_help_record(self, ctx: click.Context) -> tuple[str, str] | None:
        """The help line without the hidden aliases."""
        every = self.opts
        self.opts = [name for name in every if name not in self.hidden_aliases]
        try:
            return super().get_help_record(ctx)
        finally:
            self.opts = every


def out_option(
    help: str,
    *,
    dest: str = "out",
    kind: OutputKind = "file",
    required: bool = False,
    default: Path | None = None,
    short: bool = True,
) -> Callable[[F], F]:
    """``-o/--out PATH`` (``--output`` also accepted, not shown), passed as ``dest``.

    Args:
        help: what is written there.
        dest: name of the command's parameter.
        kind: what the path names and when it may already exist (see
            :class:`~rfsas_hw.cli.outopts.OutputPath`: every command's outputs are checked
            against its inputs and existing files before it opens anything).
        required: whether the command needs it.
        default: the path without the option (shown in ``--help``).
        short: also take ``-o`` (False where ``-o`` means something else).
    """
    names = ["-o", "--out", "--output"] if short else ["--out", "--output"]
    return click.option(
        *names,
        dest,
        cls=AliasedOption,
        hidden_aliases=("--output",),
        type=OutputPath(kind),
        required=required,
        default=default,
        show_default=default is not None,
        help=help,
    )


def duration_option(
    help: str = "Stop after this many seconds (default: Ctrl-C).",
    *,
    default: float | None = None,
) -> Callable[[F], F]:
    """``--duration SECONDS`` (positive), passed as ``duration``."""
    return click.option(
        "--duration",
        "duration",
        type=click.FloatRange(min=0, min_open=True),
        default=default,
        show_default=default is not None,
        help=help,
    )


def json_option(
    help: str = "Print one JSON object instead of a table.",
    *,
    dest: str = "as_json",
) -> Callable[[F], F]:
    """``--json`` (a flag), passed as ``dest``."""
    return click.option("--json", dest, is_flag=True, help=help)


def keys_option(
    help: str,
    *,
    required: bool = True,
) -> Callable[[F], F]:
    """``--keys DIR`` (a key directory), passed as ``keys_dir``."""
    return click.option(
        "--keys",
        "keys_dir",
        type=click.Path(file_okay=False, path_type=Path),
        required=required,
        default=None,
        help=help,
    )


def comma_numbers(text: str, count: int, option: str) -> list[float]:
    """Parse an option value of ``count`` comma-separated finite numbers.

    Raises:
        ConfigError: not ``count`` numbers, or one is not finite; the message names ``option``.
    """
    message = f"{option} {text!r}: expected {count} comma-separated numbers"
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError as err:
        raise ConfigError(message) from err
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise ConfigError(message)
    return values


def runner_options(*, default_workers: int | None = None, what: str = "seeds") -> Callable[[F], F]:
    """``--workers N`` and ``--scheduler ADDRESS`` of the project's runner
    (:mod:`rfsas_hw.parallel`), passed as ``workers`` and ``scheduler``.

    Args:
        default_workers: the default of ``--workers`` (None: the command decides, see
            :func:`rfsas_hw.parallel.default_workers`).
        what: what the workers run, for the help text.
    """
    auto = f"2 with several {what}, else 0"
    workers = click.option(
        "--workers",
        type=click.IntRange(0),
        default=default_workers,
        show_default=default_workers is not None,
        help=f"Worker processes of the local Dask cluster (0: the {what} run here, one after "
        "the other, no Dask)"
        + ("" if default_workers is not None else f" [default: {auto}]")
        + ".",
    )
    scheduler = click.option(
        "--scheduler",
        metavar="ADDRESS",
        default=None,
        help=f"Use a running Dask scheduler (tcp://host:8786) for the {what} instead of a "
        "local cluster.",
    )

    def both(f: F) -> F:
        return workers(scheduler(f))

    return both
