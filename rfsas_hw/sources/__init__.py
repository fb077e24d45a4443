"""Capture sources: one base class, one registry, drivers loaded on demand.

``rfsas_hw.sources.open("pcap:capture.pcap")`` returns a :class:`Source`;
iterate it for :class:`~rfsas_hw.records.ObservationBatch` values.
"""

from rfsas_hw.sources.base import ErrorPolicy, Source, SourceStats
from rfsas_hw.sources.registry import open_source, parse_spec, register, schemes, source_class

open = open_source

__all__ = [
    "ErrorPolicy",
    "Source",
    "SourceStats",
    "open",
    "open_source",
    "parse_spec",
    "register",
    "schemes",
    "source_class",
]
