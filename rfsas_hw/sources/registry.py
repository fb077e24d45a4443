"""Spec strings (``pcap:PATH``, ``wifi:IFACE``, …) to source classes.

Drivers are imported lazily, so a missing optional dependency of one driver
never breaks another; the error names the install command.
"""

from __future__ import annotations

import importlib
from typing import Any

from rfsas_hw.errors import ConfigError, SourceNotAvailableError
from rfsas_hw.sources.base import Source

# scheme -> "module:Class"; a driver added here is available to every command.
_LAZY: dict[str, str] = {
    "pcap": "rfsas_hw.sources.pcap:PcapSource",
    "wifi": "rfsas_hw.sources.wifi:WifiSource",
    "serial": "rfsas_hw.sources.serial_board:SerialSource",
    "virtual": "rfsas_hw.sources.virtual:VirtualSource",
    "agrelo": "rfsas_hw.sources.agrelo:AgreloSource",
    "ublox": "rfsas_hw.sources.ublox:UbloxSource",
    "kraken": "rfsas_hw.sources.kraken:KrakenSource",
    "csi": "rfsas_hw.sources.csi:CsiSource",
    "bleiq": "rfsas_hw.sources.ble_iq_source:BleIqSource",
    "bleiq+zephyr": "rfsas_hw.sources.ble_iq_zephyr_source:BleIqZephyrSource",
    "bleiq+mqtt": "rfsas_hw.link.bleiq_mqtt:BleIqMqttSource",
}
_LOADED: dict[str, type[Source[Any]]] = {}


def register(scheme: str, target: type[Source[Any]] | str) -> None:
    """Register a source class (or a lazy ``"module:Class"`` path) under ``scheme``."""
    if isinstance(target, str):
        _LAZY[scheme] = target
        _LOADED.pop(scheme, None)
    else:
        _LOADED[scheme] = target


def schemes() -> list[str]:
    """Every registered scheme name, sorted."""
    return sorted(set(_LAZY) | set(_LOADED))


def parse_spec(spec: str) -> tuple[str, str]:
    """Split ``"scheme:argument"``.

    Raises:
        ConfigError: no scheme, or an unknown one.
    """
    scheme, sep, arg = spec.partition(":")
    if not sep or not scheme:
        raise ConfigError(f"source spec {spec!r} must look like SCHEME:ARG, e.g. pcap:capture.pcap")
    if scheme not in _LAZY and scheme not in _LOADED:
        raise ConfigError(f"unknown source {scheme!r} in {spec!r}; known: {', '.join(schemes())}")
    return scheme, arg


def source_class(scheme: str) -> type[Source[Any]]:
    """The class registered under ``scheme``, importing it on first use.

    Raises:
        ConfigError: unknown scheme.
        SourceNotAvailableError: the driver or one of its dependencies is missing.
    """
    if scheme in _LOADED:
        return _LOADED[scheme]
    if scheme not in _LAZY:
        raise ConfigError(f"unknown source {scheme!r}; known: {', '.join(schemes())}")
    module_name, _, class_name = _LAZY[scheme].partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        missing = getattr(err, "name", None) or str(err)
        raise SourceNotAvailableError(
            f"source {scheme!r} needs {missing!r}, which is not installed "
            f"(install with: pip install 'rfsas-hw[sim]' or pip install {missing})"
        ) from err
    cls = getattr(module, class_name)
    if not (isinstance(cls, type) and issubclass(cls, Source)):
        raise SourceNotAvailableError(f"{_LAZY[scheme]} is not a Source subclass")
    _LOADED[scheme] = cls
    return cls


def open_source(spec: str, **options: Any) -> Source[Any]:
    """Open the source named by ``spec``; ``options`` go to the driver.

    Raises:
        ConfigError: malformed spec or unknown scheme.
        SourceError: the driver cannot open its input.
    """
    scheme, arg = parse_spec(spec)
    cls = source_class(scheme)
    return cls.from_spec(arg, **options)
