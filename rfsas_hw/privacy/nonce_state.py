"""The nonce authority's memory across restarts: the nonces it has drawn, on disk.

A restarted authority that drew new nonces for the current and next epoch would
split the deployment: parties holding the old nonces refuse the new envelopes,
parties started afterwards take them, and every message between the two sides
fails pre-authentication until both epochs are over. So the authority writes
every nonce it draws to a state file before handing it out, and a restarted
authority reads the file and hands out the same nonces again.

The file is text, mode 0600, replaced atomically (a crash leaves the old or the
new file, never a mix); it holds only the epochs the authority still keeps (8 by
default), so a stolen file links emitter ids over those epochs only::

    rfsas-hw nonce state v1 <authority id>
    <epoch> <64 hex digits>
    ...
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from rfsas_hw.errors import KeyStoreError
from rfsas_hw.outpaths import AtomicFile

STATE_FILE = "nonces.state"
"""Name of the state file in an authority's key directory."""
_HEADER = "rfsas-hw nonce state v1"
_NONCE_HEX = 64


def load_nonces(path: str | Path, authority_id: str) -> dict[int, bytes]:
    """The nonces recorded in ``path`` by authority ``authority_id`` (epoch → nonce);
    empty when the file does not exist yet.

    Raises:
        KeyStoreError: unreadable, readable by other users, written by another
            authority, or malformed (the message names the file and line).
    """
    p = Path(path)
    try:
        if p.stat().st_mode & 0o077:
            raise KeyStoreError(f"{p}: readable by other users; chmod 600 {p}")
        lines = p.read_text(encoding="ascii").splitlines()
    except FileNotFoundError:
        return {}
    except (OSError, UnicodeDecodeError) as err:
        raise KeyStoreError(f"{p}: cannot read the nonce state: {err}") from err
    if not lines or lines[0] != f"{_HEADER} {authority_id}":
        raise KeyStoreError(
            f"{p}: line 1: not the nonce state of authority {authority_id!r} "
            f"(expected {_HEADER!r} and the id)"
        )
    nonces: dict[int, bytes] = {}
    for number, line in enumerate(lines[1:], start=2):
        epoch, _, value = line.partition(" ")
        try:
            if len(value) != _NONCE_HEX:
                raise ValueError(f"{len(value)} hex digits, expected {_NONCE_HEX}")
            nonces[int(epoch)] = bytes.fromhex(value)
        except ValueError as err:
            raise KeyStoreError(f"{p}: line {number}: not '<epoch> <nonce hex>': {err}") from err
    return nonces


def save_nonces(path: str | Path, authority_id: str, nonces: Mapping[int, bytes]) -> None:
    """Replace ``path`` with ``nonces`` (mode 0600, atomically).

    Raises:
        KeyStoreError: the file cannot be written (the old one is then unchanged).
    """
    text = "".join(f"{e} {nonces[e].hex()}\n" for e in sorted(nonces))
    try:
        with AtomicFile(path, newline=None, mode=0o600) as out:
            out.stream.write(f"{_HEADER} {authority_id}\n{text}")
    except OSError as err:
        raise KeyStoreError(f"{path}: cannot write the nonce state: {err.strerror or err}") from err
