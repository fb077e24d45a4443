"""Where a command may write: never over an input, never outside its output, never
over an existing file unless asked to, never with a name an id chose.

Every command that writes a file asks :func:`check_output` first, with the
paths it reads from; ids that become parts of file names (sensor ids, scenario
names) go through :func:`safe_name`, and a file placed in an output directory
through :func:`inside`. :class:`AtomicFile` writes beside the target and
renames over it only when everything was written, so a failed or interrupted
run never leaves a half-written file where a good one was.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import stat
import tempfile
from collections.abc import Iterable
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Self

from rfsas_hw.errors import ConfigError, OutputError

STDIO = "-"
"""The name that means standard output (or input)."""

_NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


def safe_name(ident: str, what: str = "id") -> str:
    """``ident`` when it is safe as one file-name component, else an error.

    Safe: 1-64 of ``A-Z a-z 0-9 . _ -``, starting with a letter or digit (so
    no ``..``, no hidden files, no separators, no option-like names).

    Raises:
        ConfigError: naming ``what`` and the offending id.
    """
    if not isinstance(ident, str) or not _NAME_RE.fullmatch(ident):
        raise ConfigError(
            f"{what} {ident!r} cannot be used in a file name: use 1-64 of A-Z a-z 0-9 . _ - "
            "starting with a letter or digit"
        )
    return ident


def inside(directory: str | Path, name: str) -> Path:
    """``directory / name``, checked to stay inside ``directory`` once resolved.

    Raises:
        ConfigError: the joined path escapes ``directory`` (``..``, absolute
            parts, a symlink pointing elsewhere).
    """
    base = Path(directory).resolve()
    target = (base / name).resolve()
    if target != base and base not in target.parents:
        raise ConfigError(f"{name!r} would be written outside {directory}")
    return base / name


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or os.path.samefile(a, b)
    except OSError:
        return False


def check_output(
    path: str | Path,
    inputs: Iterable[str | Path] = (),
    *,
    force: bool = False,
    what: str = "output",
) -> Path:
    """Check that ``path`` may be written and return it.

    Refuses to write over any of ``inputs`` (same resolved path or the same
    inode, so a hard link or a symlink is caught too), and over an existing
    regular file unless ``force``. Devices and pipes (``/dev/null``, a FIFO)
    are fine: writing to them destroys nothing. ``-`` (standard output) is
    always fine.

    Raises:
        ConfigError: ``path`` is an input, is a directory, exists without ``force``,
            or cannot be created where it is (:func:`check_writable_dir`).
    """
    p = Path(path)
    if str(path) == STDIO:
        return p
    for source in inputs:
        if str(source) == STDIO:
            continue
        if _same_file(p, Path(source)):
            raise ConfigError(f"{what} {p} is also an input ({source}); refusing to write over it")
    try:
        mode: int | None = p.stat().st_mode
    except FileNotFoundError:
        mode = None
    except OSError as err:
        raise ConfigError(f"{what} {p}: {err.strerror or err}") from err
    if mode is not None and stat.S_ISDIR(mode):
        raise ConfigError(f"{what} {p} is a directory")
    if mode is not None and stat.S_ISREG(mode) and not force:
        raise ConfigError(f"{what} {p} exists; use --force to replace it")
    if mode is None or stat.S_ISREG(mode):
        check_writable_dir(p.parent, what=f"{what} {p}")
    return p


def check_writable_dir(directory: str | Path, *, what: str = "output") -> Path:
    """Check, before any work, that files can be made in ``directory`` and return it.

    A directory that does not exist yet is judged by the nearest one above it
    that does (where the command would create the missing ones). The check
    creates an unnamed temporary file there, so it sees what a write would: a
    directory without permission, a read-only file system, a file in the way.

    Raises:
        ConfigError: naming ``what`` and the directory: it, or the one above it that
            exists, is not a directory, or no file can be created in it.
    """
    d = Path(directory)
    base = d.absolute()
    while not base.exists() and base.parent != base:
        base = base.parent
    if not base.is_dir():
        raise ConfigError(f"{what}: {base} is not a directory")
    try:
        with tempfile.TemporaryFile(dir=base):
            pass
    except OSError as err:
        raise ConfigError(f"{what}: cannot create files in {base}: {err.strerror or err}") from err
    return d


class AtomicFile:
    """A file (text, or bytes with ``binary``) written beside its target and renamed
    over it on a clean close.

    For a device or pipe target (``/dev/null``, a FIFO) the target is opened
    directly: there is nothing to protect and renaming over a device is wrong.
    On an error inside the ``with`` block, or :meth:`discard`, the partial
    file is removed and the target is left as it was.

    Raises:
        OSError: the temporary file cannot be created or the rename fails.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        newline: str | None = "",
        binary: bool = False,
        mode: int | None = None,
    ) -> None:
        self.path = Path(path)
        self.mode = mode
        """Permissions of the file once renamed (default: 0666 less the umask)."""
        self._tmp: Path | None = None
        direct = self.path.exists() and not self.path.is_file()
        text: dict[str, Any] = {} if binary else {"encoding": "utf-8", "newline": newline}
        open_mode = "wb" if binary else "w"
        if direct:
            self.stream: IO[Any] = self.path.open(open_mode, **text)
        else:
            fd, tmp = tempfile.mkstemp(
                prefix=f".{self.path.name}.", suffix=".part", dir=self.path.parent or "."
            )
            self._tmp = Path(tmp)
            self.stream = os.fdopen(fd, open_mode, **text)

    def commit(self) -> None:
        """Flush, sync and rename over the target.

        Raises:
            OSError: writing, syncing or renaming failed (the target is unchanged).
        """
        try:
            self.stream.flush()
            if self._tmp is not None:
                os.fsync(self.stream.fileno())
        finally:
            self.stream.close()
        if self._tmp is not None:
            os.chmod(self._tmp, 0o666 & ~_UMASK if self.mode is None else self.mode)
            os.replace(self._tmp, self.path)
            self._tmp = None

    def discard(self) -> None:
        """Close and remove the partial file; the target is unchanged."""
        with contextlib.suppress(OSError):
            self.stream.close()
        if self._tmp is not None:
            with contextlib.suppress(OSError):
                self._tmp.unlink()
            self._tmp = None

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# read once, at import: os.umask is process-wide and racy to query later from threads
_UMASK = _read_umask()


def write_text_atomic(path: str | Path, text: str | bytes) -> None:
    """Write ``text`` (or bytes) to ``path`` through :class:`AtomicFile`.

    Raises:
        ConfigError: the file cannot be created (no such directory, no permission).
        OutputError: writing it failed (disk full, I/O error); the target is unchanged.
    """
    if isinstance(text, bytes):
        write_chunks_atomic(path, (text,))
    else:
        write_chunks_atomic(path, (text,), binary=False)


def write_chunks_atomic(
    path: str | Path, chunks: Iterable[str] | Iterable[bytes], *, binary: bool = True
) -> None:
    """Write ``chunks`` to ``path`` through :class:`AtomicFile` as they come.

    The chunks are written one by one, so a long output (an export of a large
    run log) never needs to be in memory at once. An exception raised by
    ``chunks`` itself (the producer: an unreadable input) passes unchanged, and
    like any failure it leaves the target as it was.

    Raises:
        ConfigError: the file cannot be created (no such directory, no permission).
        OutputError: writing it failed (disk full, I/O error); the target is unchanged.
    """
    try:
        out = AtomicFile(path, newline=None, binary=binary)
    except OSError as err:
        raise ConfigError(f"{path}: cannot write: {err.strerror or err}") from err
    try:
        for chunk in chunks:
            try:
                out.stream.write(chunk)
            except OSError as err:
                raise OutputError(f"{path}: write failed: {err.strerror or err}") from err
        try:
            out.commit()
        except OSError as err:
            raise OutputError(f"{path}: write failed: {err.strerror or err}") from err
    finally:
        out.discard()  # after a commit: nothing left to remove


def save_figure(fig: Any, path: str | Path, **options: Any) -> Path:
    """Save a matplotlib figure to ``path`` through :func:`write_text_atomic`.

    The image is drawn in memory first (its format from the suffix): matplotlib
    writing to a file itself does not report every failed write.

    Raises:
        ConfigError: the file cannot be created.
        OutputError: writing it failed (disk full); the target is unchanged.
    """
    p = Path(path)
    image = io.BytesIO()
    fmt = p.suffix.lstrip(".").lower() or "png"
    if fmt not in fig.canvas.get_supported_filetypes():
        raise ConfigError(f"{p}: cannot draw a .{fmt} image; use .png, .svg or .pdf")
    fig.savefig(image, format=fmt, **options)
    write_text_atomic(p, image.getvalue())
    return p
