"""Typed configuration: dataclasses filled from YAML, environment and CLI.

Precedence is CLI > environment (``RFSAS_<SECTION>_<KEY>``) > file > defaults.
Unknown keys are rejected with the file and key path, so a typo never silently
falls back to a default.
"""

from __future__ import annotations

import dataclasses
import math
import os
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from rfsas_hw.errors import ConfigError, RfsasError

T = TypeVar("T")


MAX_TEXT_BYTES = 64 * 1024 * 1024
"""Largest text input (YAML, CSV, key card) read into memory, bytes."""


def read_text_input(
    path: str | Path,
    what: str,
    max_bytes: int = MAX_TEXT_BYTES,
    error: type[RfsasError] = ConfigError,
) -> str:
    """The text of a UTF-8 input file (a leading byte-order mark is dropped).

    Raises:
        ConfigError (or ``error``): unreadable, larger than ``max_bytes``, binary,
            or not UTF-8 (UTF-16 is named as such), with the file and the byte offset.
    """
    p = Path(path)
    try:
        with p.open("rb") as fh:
            raw = fh.read(max_bytes + 1)
    except OSError as err:
        raise error(f"{p}: cannot read: {err.strerror or err}") from err
    if len(raw) > max_bytes:
        raise error(f"{p}: larger than {max_bytes // (1024 * 1024)} MiB; not a {what} file")
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise error(f"{p}: UTF-16 text; save the {what} file as UTF-8")
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    nul = raw.find(b"\x00")
    if nul >= 0:
        raise error(f"{p}: byte {nul}: a NUL byte; this is not a {what} text file")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise error(
            f"{p}: byte {err.start}: not UTF-8 text; save the {what} file as UTF-8"
        ) from err


MAX_YAML_BYTES = 4 * 1024 * 1024
"""Largest YAML input, bytes: a calibration of every 2.4 and 5 GHz channel at 0.1° steps is
well under 1 MiB, and the YAML parser takes seconds per MiB."""
MAX_YAML_DEPTH = 64
"""Deepest nesting a YAML input may have: the parser's time grows with the square of the
depth (1,500 brackets take seconds), and no file of ours nests more than a few levels."""


def _yaml_depth(text: str) -> int:
    """An upper estimate of the nesting depth: flow brackets outside quotes and comments,
    or block indentation (a space or ``- `` per level at most)."""
    deepest = depth = 0
    quote = ""
    comment = False
    prev = "\n"
    indent = 0
    at_line_start = True
    for ch in text:
        if ch == "\n":
            comment, at_line_start, indent = False, True, 0
            quote = "" if quote == "'" else quote
        elif comment:
            pass
        elif quote:
            if ch == quote and prev != "\\":
                quote = ""
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and prev in " \t\n":
            comment = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth = max(0, depth - 1)
        if at_line_start:
            if ch in " -":
                indent += 1
                deepest = max(deepest, indent // 2)
            elif ch != "\n":
                at_line_start = False
        prev = ch
    return deepest


def parse_yaml(text: str, where: str, error: type[RfsasError] = ConfigError) -> Any:
    """Parse YAML text (safe loader) named ``where`` in errors.

    Raises:
        ConfigError (or ``error``): not valid YAML (one line, with line/column),
            or nested deeper than :data:`MAX_YAML_DEPTH`.
    """
    if _yaml_depth(text) > MAX_YAML_DEPTH:
        raise error(f"{where}: invalid YAML: nested deeper than {MAX_YAML_DEPTH} levels")
    try:
        return yaml.safe_load(text)
    except RecursionError as err:
        raise error(f"{where}: invalid YAML: nested too deeply") from err
    except ValueError as err:  # an integer of thousands of digits (Python's int limit)
        raise error(f"{where}: invalid YAML: a value too large to read ({err!s:.60})") from err
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        at = f" line {mark.line + 1}, column {mark.column + 1}:" if mark is not None else ""
        problem = " ".join(str(getattr(err, "problem", None) or err).split())
        raise error(f"{where}:{at} invalid YAML: {problem}") from err


def read_yaml(path: str | Path) -> Any:
    """Parse a YAML file.

    Raises:
        ConfigError: the file is missing or is not valid YAML (with line/column).
    """
    p = Path(path)
    return parse_yaml(read_text_input(p, "YAML", MAX_YAML_BYTES), str(p))


def _key_path(where: str, key: str) -> str:
    """``file.yaml: key`` at the top of a file, ``section.key`` below it."""
    if where.endswith((".yaml", ".yml", ".json")):
        return f"{where}: {key}"
    return f"{where}.{key}"


def _convert(value: Any, hint: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if hint is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(value, arg, where)
            except ConfigError as err:
                errors.append(str(err))
        raise ConfigError(errors[0] if errors else f"{where}: unexpected value {value!r}")
    if origin is typing.Literal:
        if value not in args:
            choices = ", ".join(repr(a) for a in args)
            raise ConfigError(f"{where}: {value!r} is not one of {choices}")
        return value
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
        return from_mapping(hint, value, where)
    if origin in (list, tuple) or hint in (list, tuple):
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {type(value).__name__}")
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                raise ConfigError(f"{where}: expected {len(args)} items, got {len(value)}")
            return tuple(
                _convert(v, a, f"{where}[{i}]")
                for i, (v, a) in enumerate(zip(value, args, strict=True))
            )
        item = args[0] if args else Any
        items = [_convert(v, item, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if (origin is tuple or hint is tuple) else items
    if origin is dict or hint is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
        kt, vt = args if args else (Any, Any)
        return {
            _convert(k, kt, where): _convert(v, vt, _key_path(where, str(k)))
            for k, v in value.items()
        }
    if hint is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in (
            "1",
            "true",
            "yes",
            "on",
            "0",
            "false",
            "no",
            "off",
        ):
            return value.lower() in ("1", "true", "yes", "on")
        raise ConfigError(f"{where}: expected true/false, got {value!r}")
    if hint is float:
        if isinstance(value, bool):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        try:
            number = float(value)
        except (TypeError, ValueError) as err:
            raise ConfigError(f"{where}: expected a number, got {value!r}") from err
        if math.isnan(number):  # never a setting: it would poison every result silently
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return number
    if hint is int:
        if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        try:
            return int(value)
        except (TypeError, ValueError) as err:
            raise ConfigError(f"{where}: expected an integer, got {value!r}") from err
    if hint is str:
        if not isinstance(value, str | int | float) or isinstance(value, bool):
            raise ConfigError(f"{where}: expected text, got {value!r}")
        return str(value)
    if hint is Path:
        return Path(str(value))
    return value


def from_mapping(cls: type[T], data: Mapping[str, Any], where: str = "config") -> T:
    """Build dataclass ``cls`` from ``data``, checking keys and types.

    ``where`` prefixes error messages (a file name, a key path).

    Raises:
        ConfigError: an unknown key, a missing required key, or a wrong type.
    """
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = [k for k in data if k not in fields]
    if unknown:
        known = ", ".join(sorted(fields))
        raise ConfigError(f"{where}: unknown key {unknown[0]!r} (known: {known})")
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        if name in data:
            kwargs[name] = _convert(data[name], hints[name], _key_path(where, name))
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{where}: missing required key {name!r}")
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (TypeError, ValueError, RfsasError) as err:
        raise ConfigError(f"{where}: {err}") from err


def env_overrides(
    section: str, cls: type[Any], environ: Mapping[str, str] | None = None
) -> dict[str, str]:
    """Values from ``RFSAS_<SECTION>_<FIELD>`` environment variables for ``cls``'s fields."""
    env = os.environ if environ is None else environ
    prefix = f"RFSAS_{section.upper()}_"
    names = {f.name for f in dataclasses.fields(cls)}
    return {
        k[len(prefix) :].lower(): v
        for k, v in env.items()
        if k.startswith(prefix) and k[len(prefix) :].lower() in names
    }


def load(
    cls: type[T],
    path: str | Path | None = None,
    *,
    section: str | None = None,
    cli: Mapping[str, Any] | None = None,
    environ: Mapping[str, str] | None = None,
) -> T:
    """Layer defaults < file (optionally one ``section`` of it) < environment < CLI.

    CLI values that are None are treated as not given.

    Raises:
        ConfigError: unreadable file, unknown key, wrong type.
    """
    merged: dict[str, Any] = {}
    where = "config"
    if path is not None:
        where = str(path)
        data = read_yaml(path) or {}
        if section is not None:
            data = data.get(section, {}) if isinstance(data, Mapping) else data
            where = f"{path}: {section}"
        if not isinstance(data, Mapping):
            raise ConfigError(f"{where}: expected a mapping at the top level")
        merged.update(data)
    merged.update(env_overrides(section or cls.__name__, cls, environ))
    if cli:
        merged.update({k: v for k, v in cli.items() if v is not None})
    return from_mapping(cls, merged, where)
