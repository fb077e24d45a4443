"""Fixtures for link tests."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import pytest

# pytest runs with --import-mode=importlib, which does not put test folders on
# sys.path; the link tests share one helper module from this folder.
sys.path.insert(0, str(Path(__file__).parent))

from linkhelp import key, message

from rfsas_hw.link import SafetyMessage, Signer, TrustedKeys


@pytest.fixture
def signer() -> Signer:
    return Signer("rsu-1", key(0x1234))


@pytest.fixture
def trust(signer: Signer) -> TrustedKeys:
    return TrustedKeys({"rsu-1": signer.public_key, "obu-9": key(0x9999).public_key()})


@pytest.fixture
def make() -> Callable[..., SafetyMessage]:
    return message
