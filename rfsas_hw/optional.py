"""Lazy imports of optional dependencies with an error that says how to install them."""

from __future__ import annotations

import importlib
from types import ModuleType

from rfsas_hw.errors import MissingDependencyError

EXTRAS = {
    "matplotlib": "plot",
    "gymnasium": "sim",
    "pygame": "sim",
    "stable_baselines3": "rl",
    "PIL": "plot",
    "csiread": "csi",
    "aiohttp": "web",
    "asn1tools": "v2x",
    "distributed": "ncap",
    "dask": "ncap",
}


def require(module: str) -> ModuleType:
    """Import ``module`` or raise an error naming the extra that provides it.

    Raises:
        MissingDependencyError: the module is not installed.
    """
    try:
        return importlib.import_module(module)
    except ImportError as err:
        top = module.split(".")[0]
        extra = EXTRAS.get(top)
        how = f"pip install 'rfsas-hw[{extra}]'" if extra else f"pip install {top}"
        raise MissingDependencyError(f"{top} is not installed; install it with: {how}") from err


def pyplot() -> ModuleType:
    """matplotlib.pyplot with the non-interactive Agg backend.

    Raises:
        MissingDependencyError: matplotlib is not installed.
    """
    mpl = require("matplotlib")
    mpl.use("Agg")
    return require("matplotlib.pyplot")
