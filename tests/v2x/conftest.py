"""Fixtures for the V2X tests: the independent decoder (pycrate), compiled once."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

# --import-mode=importlib does not put test folders on sys.path; the V2X tests share
# helper modules from this folder.
sys.path.insert(0, str(Path(__file__).parent))

pytest.importorskip("asn1tools", reason="the v2x extra (asn1tools) is not installed")

from pycrate_cpm import PycrateCpm, compile_pycrate


@pytest.fixture(scope="session")
def pycrate_cpm(tmp_path_factory: pytest.TempPathFactory) -> PycrateCpm:
    """pycrate's CPM codec, compiled from the package's ASN.1 modules."""
    pytest.importorskip("pycrate_asn1c", reason="pycrate (dev extra) is not installed")
    return PycrateCpm(compile_pycrate(tmp_path_factory.mktemp("pycrate")))
