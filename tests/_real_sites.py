"""A glacier-sized site shaped by a real DEM (``scripts/real_dems.py``), or a skip that says
why when the DEM cannot be had (no registry, no cache)."""

from __future__ import annotations

import sys
from pathlib import Path
from types import ModuleType

import pytest
import xarray as xr

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def real_site(name: str, **site: int) -> tuple[ModuleType, xr.DataArray]:
    """``(real_dems, real_dems.glacier_site(name, **site))``; skips the test when the DEM is
    unavailable."""
    sys.path.insert(0, str(SCRIPTS))
    import real_dems

    try:
        return real_dems, real_dems.glacier_site(name, **site)
    except real_dems.RealDataUnavailable as exc:
        pytest.skip(f"real DEM {name!r} unavailable: {exc}")
