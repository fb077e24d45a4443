"""``URL#key=value&key=value`` source specs: the options after the ``#``.

The bearing-unit drivers (``ublox:``, ``agrelo:``, ``kraken:``) take their
settings in the spec itself, each key mapped to a constructor argument and a
type. An option given in the spec does not override one the caller passes.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from rfsas_hw.errors import ConfigError

SpecKeys = Mapping[str, tuple[str, Callable[[str], Any]]]
"""Spec key → (constructor argument, type converting the text)."""


def split_spec(
    scheme: str, arg: str, keys: SpecKeys, options: dict[str, Any]
) -> tuple[str, dict[str, Any]]:
    """The URL before ``#`` and ``options`` with the spec's keys filled in.

    Args:
        scheme: the driver's scheme, for messages.
        arg: the spec after ``scheme:``.
        keys: the keys the driver accepts.
        options: keyword arguments from the caller; they win over the spec.

    Raises:
        ConfigError: an unknown key, a part without ``=``, or a value the
            key's type refuses.
    """
    url, _, opts = arg.partition("#")
    for part in filter(None, opts.split("&")):
        key, sep, value = part.partition("=")
        if not sep or key not in keys:
            raise ConfigError(f"{scheme} option {part!r}: use key=value, keys {', '.join(keys)}")
        name, typ = keys[key]
        try:
            options.setdefault(name, typ(value))
        except ValueError as err:
            raise ConfigError(f"{scheme} option {part!r}: {err}") from err
    return url, options


__all__ = ["SpecKeys", "split_spec"]
