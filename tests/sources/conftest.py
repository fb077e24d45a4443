"""Fixtures for the capture-source tests."""

from __future__ import annotations

import sys
from pathlib import Path

# The tests share the independent radiotap writer in this folder.
sys.path.insert(0, str(Path(__file__).parent))
