"""Optional features and the pip extras that bring them, with the one-line error a missing one gives.

The core install (``pip install ardupilot-nav-companion``) is what ``companion run`` and ``replay`` need on a
companion computer. Heavier features come with extras named for what they add; a feature used without its extra
raises :class:`MissingExtra`, which the command line prints as one line naming the extra (exit 2).
"""

from __future__ import annotations

import importlib
from types import ModuleType

#: the distribution's name on PyPI (the import package and the command are ``companion``)
DISTRIBUTION = "ardupilot-nav-companion"

#: extra -> what it adds (the packages are in pyproject.toml's [project.optional-dependencies])
EXTRAS = {
    "gravity": "netCDF gravity maps and a serial gravimeter (xarray, netCDF4, pyserial)",
    "foxglove": "the live Foxglove view of `companion run --foxglove` (foxglove-sdk)",
    "plots": "the benchmarks' and the sample generator's plots (matplotlib)",
    "dask": "Monte Carlo sweeps on a Dask cluster (dask.distributed)",
}


class MissingExtra(ImportError):
    """A feature needs an extra that is not installed; the message is the one line to show."""


def require(module: str, extra: str, feature: str) -> ModuleType:
    """``module`` imported, or MissingExtra naming ``extra`` when it (or a package it needs) is not installed."""
    try:
        return importlib.import_module(module)
    except ImportError as err:
        missing = err.name or module
        raise MissingExtra(f"{feature} needs the [{extra}] extra ({missing} is not installed): "
                           f"pip install '{DISTRIBUTION}[{extra}]'") from None
