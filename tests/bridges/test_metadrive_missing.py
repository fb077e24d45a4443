"""Without MetaDrive (the main virtual environment) the adapter says how to get it."""

from __future__ import annotations

import importlib.util

import pytest

from rfsas_hw.errors import MissingDependencyError


@pytest.mark.skipif(
    importlib.util.find_spec("metadrive") is not None, reason="MetaDrive is installed here"
)
def test_missing_metadrive_names_the_make_target() -> None:
    from rfsas_hw.bridges.metadrive import asset_problem, make_scene, require_metadrive

    for call in (make_scene, require_metadrive, asset_problem):
        with pytest.raises(MissingDependencyError, match="make metadrive"):
            call()
