"""The files a SUMO run reads, checked before SUMO sees them.

SUMO's XML reader expands entities a document type declaration defines, so a
scenario with a "billion laughs" DTD grows SUMO's memory without bound. No
SUMO file needs a DTD: :func:`sumo_inputs` refuses any file that has one and
returns every file a ``.sumocfg`` names in its ``<input>`` section (the net,
routes, additional files), so that a command can also keep its outputs off
them.
"""

from __future__ import annotations

import xml.parsers.expat
from pathlib import Path
from typing import Any

from rfsas_hw.errors import ConfigError

PROLOG_BYTES = 64 * 1024
"""A file's prolog (before its root element) is looked for a DTD in this many bytes."""
MAX_SUMOCFG_BYTES = 4 * 1024 * 1024
"""A ``.sumocfg`` larger than this is refused (real ones are a few kB)."""


class _PrologEndError(Exception):
    """The root element started: the prolog had no DTD."""


def _refuse_dtd(path: Path, *_: Any) -> None:
    raise ConfigError(
        f"{path}: has a document type declaration (<!DOCTYPE>); SUMO files need none and "
        "its entities could grow without bound: remove it"
    )


def _parser(path: Path) -> Any:
    parser = xml.parsers.expat.ParserCreate()
    parser.StartDoctypeDeclHandler = lambda *a: _refuse_dtd(path)
    parser.EntityDeclHandler = lambda *a: _refuse_dtd(path)
    return parser


def check_no_dtd(path: str | Path) -> None:
    """Refuse an XML file whose prolog declares a document type.

    Raises:
        ConfigError: the file cannot be read, is not XML, or has a DTD.
    """
    p = Path(path)
    parser = _parser(p)

    def stop(*_: Any) -> None:
        raise _PrologEndError

    parser.StartElementHandler = stop
    try:
        with p.open("rb") as fh:
            head = fh.read(PROLOG_BYTES)
        parser.Parse(head, len(head) < PROLOG_BYTES)
    except _PrologEndError:
        return
    except OSError as err:
        raise ConfigError(f"{p}: cannot read: {err.strerror or err}") from err
    except xml.parsers.expat.ExpatError as err:
        raise ConfigError(f"{p}: not SUMO XML: {err}") from err
    raise ConfigError(f"{p}: no XML element in its first {PROLOG_BYTES} bytes")


def sumo_inputs(path: str | Path) -> list[Path]:
    """``path`` and every file its ``<input>`` section names (for a ``.sumocfg``),
    each checked to have no DTD; for a net file, just ``path``.

    Raises:
        ConfigError: a file is missing, unreadable, too large, not XML, or has a DTD.
    """
    p = Path(path)
    if p.suffix != ".sumocfg":
        check_no_dtd(p)
        return [p]
    try:
        if p.stat().st_size > MAX_SUMOCFG_BYTES:
            raise ConfigError(f"{p}: larger than {MAX_SUMOCFG_BYTES} bytes; not a SUMO config")
        data = p.read_bytes()
    except OSError as err:
        raise ConfigError(f"{p}: cannot read: {err.strerror or err}") from err
    parser = _parser(p)
    names: list[str] = []
    depth: list[str] = []

    def start(tag: str, attrs: dict[str, str]) -> None:
        if depth and depth[-1] == "input" and "value" in attrs:
            names.extend(n.strip() for n in attrs["value"].split(",") if n.strip())
        depth.append(tag)

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: depth.pop()
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as err:
        raise ConfigError(f"{p}: not a SUMO config: {err}") from err
    found = [p]
    for name in names:
        named = Path(name) if Path(name).is_absolute() else p.parent / name
        if not named.is_file():
            raise ConfigError(f"{p}: names {name!r}, which is not a file")
        check_no_dtd(named)
        found.append(named)
    return found
