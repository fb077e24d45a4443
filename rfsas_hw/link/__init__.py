"""The link: signed safety messages, their verification, replay and latency watch, transports."""

from rfsas_hw.link.latency import LatencyConfig, LatencyWatch, LinkState, SenderLatency
from rfsas_hw.link.message import (
    DEFAULT_DATAGRAM,
    MAX_DATAGRAM,
    MessageFormatError,
    SafetyMessage,
    decode,
    encode_body,
    max_bearings,
)
from rfsas_hw.link.publisher import Publisher, PublisherStats
from rfsas_hw.link.receiver import (
    REASONS,
    Receiver,
    ReceiverConfig,
    ReceiverStats,
    VerifiedMessage,
)
from rfsas_hw.link.signing import SenderKeys, Signer, TrustedKeys, verify
from rfsas_hw.link.transport import Transport, UdpEndpoint, UdpTransport, open_transport, parse_url

__all__ = [
    "DEFAULT_DATAGRAM",
    "MAX_DATAGRAM",
    "REASONS",
    "LatencyConfig",
    "LatencyWatch",
    "LinkState",
    "MessageFormatError",
    "Publisher",
    "PublisherStats",
    "Receiver",
    "ReceiverConfig",
    "ReceiverStats",
    "SafetyMessage",
    "SenderKeys",
    "SenderLatency",
    "Signer",
    "Transport",
    "TrustedKeys",
    "UdpEndpoint",
    "UdpTransport",
    "VerifiedMessage",
    "decode",
    "encode_body",
    "max_bearings",
    "open_transport",
    "parse_url",
    "verify",
]
