"""One rooted exception tree for everything rfsas-hw raises on purpose.

Every error says what was wrong and where (file, line, key, frame number, byte
offset). Errors that wrap a lower-level failure chain it with ``raise … from``.
The CLI turns any :class:`RfsasError` into one line on stderr and exit code 2
(:class:`OutputError`, a write that failed, into exit code 1).
"""

from __future__ import annotations


class RfsasError(Exception):
    """Root of every error rfsas-hw raises deliberately."""


class ConfigError(RfsasError):
    """A configuration value or file is invalid (unknown key, wrong type, bad range)."""


class DataFormatError(RfsasError):
    """An input file (CSV, YAML, JSONL) does not have the expected shape."""


class CalibrationError(RfsasError):
    """A calibration cannot be fitted, loaded or applied."""


class CaptureFormatError(RfsasError):
    """A capture (pcap, pcapng, radiotap, 802.11) is malformed.

    The message names the file, the frame number and the byte offset.
    """


class SourceError(RfsasError):
    """A capture source cannot be opened or read (device, interface, permissions)."""


class SourceNotAvailableError(SourceError):
    """A source needs an optional dependency or a platform feature that is missing."""


class BoardProtocolError(RfsasError):
    """A DF-board frame or message violates the firmware protocol."""


class CpmFormatError(DataFormatError):
    """A Collective Perception Message (or the GeoNetworking/BTP frame around it)
    cannot be decoded or encoded; the message says which field and why."""


class LinkError(RfsasError):
    """A safety message cannot be built, sent or received."""


class LinkSecurityError(LinkError):
    """A safety message failed verification: signature, replay, stale, unknown sender."""


class KeyStoreError(RfsasError):
    """Key files are missing, malformed, or would be overwritten."""


class BackendError(RfsasError):
    """The backend cannot compute a result from its inputs."""


class SimulationError(RfsasError):
    """A scenario or simulation run is invalid."""


class ExportError(RfsasError):
    """A run cannot be exported (unreadable log, no site origin, unwritable output)."""


class OutputError(RfsasError):
    """An output could not be written while the command ran (disk full, I/O error).

    Unlike the other errors (bad input, exit code 2) this is a failed run: the
    CLI prints ``failed: MESSAGE`` and exits with code 1.
    """


class MissingDependencyError(RfsasError):
    """An optional dependency is not installed; the message names the install command."""
