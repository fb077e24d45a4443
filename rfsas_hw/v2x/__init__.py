"""V2X: RF-SAS tracks as ETSI Collective Perception Messages (CPM v2, TS 103 324 v2.1.1).

- :mod:`~rfsas_hw.v2x.model`: what a CPM says, in SI units and the CPM's frames;
- :mod:`~rfsas_hw.v2x.codec`: UPER encoding and strict decoding (``asn1tools``, the
  ``v2x`` extra; the standard's ASN.1 modules are package data in ``asn1/``);
- :mod:`~rfsas_hw.v2x.timestamp`: ``TimestampIts``, TAI ms since 2004 with leap seconds;
- :mod:`~rfsas_hw.v2x.perception`: the backend's tracks → CPMs (object ids, inclusion
  rules, sensor information, segmentation);
- :mod:`~rfsas_hw.v2x.geonet`: GeoNetworking + BTP-B framing and pcap files;
- :mod:`~rfsas_hw.v2x.sink`: the backend's live CPM output (UDP, BTP-B, MQTT);
- :mod:`~rfsas_hw.v2x.listen`: receiving CPMs from any station;
- :mod:`~rfsas_hw.v2x.export`: a recorded run as a pcap of CPM frames.

See docs/v2x.md for field sources, units, frames and the class mapping.
"""

from __future__ import annotations

from rfsas_hw.v2x.codec import decode_cpm, decode_cpm_tree, encode_cpm
from rfsas_hw.v2x.model import Cpm, PerceivedObject, ReferencePoint, SensorEntry
from rfsas_hw.v2x.perception import CpmConfig, CpmGenerator, EncodedCpm
from rfsas_hw.v2x.timestamp import its_ms_from_utc_ns, utc_ns_from_its_ms

__all__ = [
    "Cpm",
    "CpmConfig",
    "CpmGenerator",
    "EncodedCpm",
    "PerceivedObject",
    "ReferencePoint",
    "SensorEntry",
    "decode_cpm",
    "decode_cpm_tree",
    "encode_cpm",
    "its_ms_from_utc_ns",
    "utc_ns_from_its_ms",
]
