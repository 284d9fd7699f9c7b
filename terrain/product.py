"""The terrain product (DESIGN.md §3): an ``xarray.Dataset`` with ``elevation`` and
``elevation_std`` (metres) on dims ``(y, x)`` of a :class:`Grid`, CRS and provenance in attrs."""

from __future__ import annotations

from typing import Any

from .grid import Grid

__all__ = ["software_version", "terrain_dataset"]


def software_version() -> str:
    """The installed glacimap version ("unknown" when running from a bare source tree)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("glacimap")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"


def terrain_dataset(grid: Grid, elevation: Any, elevation_std: Any, attrs: dict[str, Any]):
    """Wrap mean and 1-sigma arrays of shape ``grid.shape`` (numpy or dask) as the product."""
    import xarray as xr

    return xr.Dataset(
        {
            "elevation": (
                ("y", "x"),
                elevation,
                {"units": "m", "long_name": "posterior mean elevation"},
            ),
            "elevation_std": (
                ("y", "x"),
                elevation_std,
                {"units": "m", "long_name": "posterior 1-sigma of elevation"},
            ),
        },
        coords=grid.coords(),
        attrs={**grid.attrs(), **attrs},
    )
