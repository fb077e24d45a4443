"""Output options of every command: one type marks them, one check runs before any work.

An option whose value is a path the command writes has the type
:class:`OutputPath`. :func:`guard_outputs` (applied by the entry point to every
command) gives each such command a ``--force`` flag when it has none, and wraps
its callback so that, before the command opens anything:

* no output is one of the command's inputs (every other path option or
  argument, and the files inside an input directory), nor another output;
* an existing output file is replaced only with ``--force``; a file that must
  be new (a secret, a key card) and a new directory (a rosbag2 bag) are never
  replaced;
* a write that fails while the command runs (disk full, I/O error) ends as
  :class:`~rfsas_hw.errors.OutputError`: one line on stderr and exit code 1.

A new command inherits all of this by giving its output options the type
``OutputPath``; paths it derives itself (one file per seed, a default name)
it checks with :func:`~rfsas_hw.outpaths.check_output` and its ``force``.
"""

from __future__ import annotations

import errno
import functools
import itertools
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Literal

import click

from rfsas_hw.errors import ConfigError, OutputError
from rfsas_hw.outpaths import STDIO, check_output, check_writable_dir

OutputKind = Literal["file", "new_file", "dir", "new_dir", "file_or_new_dir", "update"]

WRITE_ERRNOS = frozenset(
    {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EROFS, errno.EPIPE}
)
"""Errors of a write that failed under a running command (not of a bad name)."""

INPUT_DIR_FILES = 2000
"""At most this many files inside an input directory are checked against the outputs."""


class OutputPath(click.Path):
    """A path option the command writes.

    Args:
        kind: ``file`` (a file, replaced only with ``--force``); ``new_file``
            (a file that must not exist); ``dir`` (a directory the command
            writes into, and which checks its own files); ``new_dir`` (a
            directory that must not exist);
            ``file_or_new_dir`` (either, by what the command is asked to write);
            ``update`` (a file read, then written back: never another input).
    """

    def __init__(self, kind: OutputKind = "file") -> None:
        super().__init__(
            file_okay=kind not in ("dir", "new_dir"),
            dir_okay=kind in ("dir", "new_dir", "file_or_new_dir"),
            path_type=Path,
        )
        self.kind: OutputKind = kind


def output_params(command: click.Command) -> list[click.Parameter]:
    """The parameters of ``command`` that name an output."""
    return [p for p in command.params if isinstance(p.type, OutputPath)]


def _values(value: Any) -> Iterator[Path]:
    if value is None:
        return
    if isinstance(value, tuple | list):
        for v in value:
            yield from _values(v)
    elif isinstance(value, str | Path) and str(value) not in ("", STDIO):
        yield Path(value)


def _named_files(value: Any) -> Iterator[Path]:
    """Existing files a text option names: ``FILE``, ``scheme:FILE`` or ``A+B``
    (source specs such as ``pcap:a.pcap+b.pcap``)."""
    if not isinstance(value, str) or not value:
        return
    for text in {value, value.partition(":")[2]}:
        for part in text.split("+"):
            if part and Path(part).is_file():
                yield Path(part)


def _inputs(command: click.Command, params: dict[str, Any]) -> list[Path]:
    """Every path the command reads, as far as its options say: path options and
    arguments (files inside input directories included, up to
    :data:`INPUT_DIR_FILES`), and existing files that text options name."""
    found: list[Path] = []
    for p in command.params:
        if p.name is None or isinstance(p.type, OutputPath):
            continue
        if not isinstance(p.type, click.Path):
            values = params.get(p.name)
            for value in values if isinstance(values, tuple | list) else [values]:
                found.extend(_named_files(value))
            continue
        for path in _values(params.get(p.name)):
            found.append(path)
            if path.is_dir():
                files = (f for f in path.rglob("*") if f.is_file())
                found.extend(itertools.islice(files, INPUT_DIR_FILES))
    return found


def check_outputs(command: click.Command, params: dict[str, Any], force: bool) -> None:
    """Check every output option of ``command`` (values in ``params``) before any work.

    Raises:
        ConfigError: an output is an input or another output, an existing file
            without ``force``, a directory output that cannot be one, or an output
            where no file can be created.
    """
    inputs = _inputs(command, params)
    seen: list[tuple[str, Path]] = []
    for p in output_params(command):
        assert isinstance(p.type, OutputPath) and p.name is not None
        # the name --help shows, not an old one kept as a hidden alias (--output)
        hidden = getattr(p, "hidden_aliases", ())
        what = max([o for o in getattr(p, "opts", [p.name]) if o not in hidden], key=len)
        for path in _values(params.get(p.name)):
            for other_what, other in seen:
                if path.resolve() == other.resolve():
                    raise ConfigError(f"{what} {path} is also {other_what}; give two names")
            seen.append((what, path))
            kind = p.type.kind
            if kind == "file_or_new_dir":
                kind = "new_dir" if path.is_dir() else "file"
            if kind == "file":
                check_output(path, inputs, force=force, what=what)
            elif kind == "update":
                check_output(path, inputs, force=True, what=what)
                if path.exists() and not path.is_file():
                    raise ConfigError(f"{what} {path} is read and written back: name a file")
            elif kind == "new_file":
                check_output(path, inputs, force=True, what=what)
                if path.exists() or path.is_symlink():
                    raise ConfigError(f"{what} {path} already exists; refusing to overwrite it")
            else:
                _check_dir(path, inputs, kind, what)


def _check_dir(path: Path, inputs: list[Path], kind: str, what: str) -> None:
    for source in inputs:
        try:
            same = path.resolve() == source.resolve()
        except OSError:
            same = False
        if same:
            raise ConfigError(f"{what} {path} is also an input; refusing to write into it")
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{what} {path} exists and is not a directory")
    if kind == "new_dir" and path.exists():
        raise ConfigError(f"{what} {path} exists; the directory must be new")
    check_writable_dir(path, what=f"{what} {path}")


def _named(outputs: list[str]) -> str:
    return f" ({', '.join(outputs)})" if outputs else ""


def _guarded(
    command: click.Command, callback: Callable[..., Any], injected_force: bool
) -> Callable[..., Any]:
    @functools.wraps(callback)
    def run(*args: Any, **kwargs: Any) -> Any:
        force = bool(kwargs.pop("force", False) if injected_force else kwargs.get("force"))
        check_outputs(command, kwargs, force)
        try:
            return callback(*args, **kwargs)
        except OSError as err:
            if err.errno not in WRITE_ERRNOS:
                raise
            names = [
                str(path)
                for p in output_params(command)
                if p.name is not None
                for path in _values(kwargs.get(p.name))
            ]
            raise OutputError(f"a write failed{_named(names)}: {err.strerror or err}") from err

    return run


FORCE_HELP = "Replace existing output files (never an input)."


def guard_outputs(command: click.Command) -> None:
    """Apply the output rules to ``command`` and, for a group, to every subcommand.

    Idempotent: a command is guarded once.
    """
    if isinstance(command, click.Group):
        for sub in command.commands.values():
            guard_outputs(sub)
        return
    if getattr(command, "_outputs_guarded", False) or command.callback is None:
        return
    outputs = output_params(command)
    if not outputs:
        return
    replaceable = any(
        isinstance(p.type, OutputPath) and p.type.kind in ("file", "file_or_new_dir")
        for p in outputs
    )
    injected = replaceable and not any(p.name == "force" for p in command.params)
    if injected:
        command.params.append(click.Option(["--force"], is_flag=True, help=FORCE_HELP))
    command.callback = _guarded(command, command.callback, injected)
    command._outputs_guarded = True  # type: ignore[attr-defined]
