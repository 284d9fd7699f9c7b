"""``glacimap plan``: a survey plan over a region, with its coverage metrics."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from terrain.errors import InputError, bad_input

console = Console()


_NETCDF = (".nc", ".nc4", ".cdf", ".netcdf")


def _read_prior(path: Path | None):
    """The prior DEM as a north-up DataArray in a projected CRS (m), or the embedded site.

    Any raster GDAL reads (GeoTIFF, COG, VRT, ...) goes through :class:`terrain.RasterMean`
    on its own cells; a NetCDF file is opened by xarray (its ``elevation`` variable, or its
    only 2-D one; CRS as :func:`terrain.grid.dataarray_crs` finds it). A DEM in a geographic
    CRS is reprojected (bilinear) to the UTM zone of its centre.
    """
    from terrain import RasterMean, default_site

    if path is None:
        return default_site(resolution=4.0)
    if not path.is_file():
        raise bad_input(
            "--prior", str(path), "an existing DEM file (GeoTIFF or NetCDF)", "check the path"
        )
    source = _netcdf_dem(path) if path.suffix.lower() in _NETCDF else path
    try:
        mean = RasterMean(source, offset="none")
    except InputError as exc:
        raise bad_input(
            "--prior", str(path), "a DEM raster GDAL or xarray reads (GeoTIFF, NetCDF)", str(exc)
        ) from exc
    crs, (w, s, e, n) = _planning_frame(mean.source)
    dem = mean.bind(crs, (w, s, e, n)).bound_dem  # north-up, with a margin of a few cells
    return dem.sel(x=slice(w, e), y=slice(n, s))


def _netcdf_dem(path: Path):
    import xarray as xr

    try:
        ds = xr.open_dataset(path)
    except (OSError, ValueError) as exc:
        raise bad_input(
            "--prior", str(path), "a NetCDF file xarray can open", f"{exc} (or pass a GeoTIFF)"
        ) from exc
    two_d = [v for v in ds.data_vars if ds[v].ndim == 2]
    name = "elevation" if "elevation" in ds else (two_d[0] if len(two_d) == 1 else None)
    if name is None:
        raise bad_input(
            "--prior",
            f"{path.name} variables {list(ds.data_vars)}",
            "a variable named 'elevation' (or a single 2-D variable)",
            "rename the DEM variable to 'elevation'",
        )
    da = ds[name]
    missing = [c for c in ("x", "y") if c not in da.coords]
    if missing:
        raise bad_input(
            "--prior",
            f"{path.name}:{name} coordinates {list(da.coords)}",
            "1-D coordinates named x and y (cell centres)",
            "rename them (e.g. lon/lat -> x/y) or convert: gdal_translate in.nc out.tif",
        )
    return da.assign_attrs({**ds.attrs, **da.attrs}).load()


def _planning_frame(source) -> tuple:
    """The DEM's own CRS and footprint when projected; else the UTM zone of its centre and
    the largest rectangle in it that the DEM covers."""
    from pyproj import Transformer

    from terrain.grid import utm_crs

    w, s, e, n = source.bounds
    if source.crs.is_projected:
        return source.crs, (w, s, e, n)
    lon, lat = Transformer.from_crs(source.crs, "EPSG:4326", always_xy=True).transform(
        (w + e) / 2, (s + n) / 2
    )
    utm = utm_crs(lon, lat)
    crs = utm.to_epsg() if utm else None
    if crs is None:
        raise bad_input(
            "--prior", source.crs.name, "a projected DEM", "reproject it: gdalwarp -t_srs ..."
        )
    to_map = Transformer.from_crs(source.crs, f"EPSG:{crs}", always_xy=True)
    t = np.linspace(0.0, 1.0, 33)
    west = to_map.transform(np.full_like(t, w), s + t * (n - s))[0].max()
    east = to_map.transform(np.full_like(t, e), s + t * (n - s))[0].min()
    south = to_map.transform(w + t * (e - w), np.full_like(t, s))[1].max()
    north = to_map.transform(w + t * (e - w), np.full_like(t, n))[1].min()
    dx, dy = 1e-3 * (east - west), 1e-3 * (north - south)  # edges curve between the samples
    return f"EPSG:{crs}", (west + dx, south + dy, east - dx, north - dy)


def plan_command(
    pattern: Annotated[str, typer.Option(help="lawnmower or piecewise_continuous.")] = "lawnmower",
    swaths: Annotated[int, typer.Option(help="Number of swaths N.")] = 4,
    bounds: Annotated[
        tuple[float, float, float, float] | None,
        typer.Option(help="Region W S E N in metres (default: the prior's extent)."),
    ] = None,
    heading: Annotated[
        float | None,
        typer.Option(help="Swath heading, degrees clockwise from north (default: fewest turns)."),
    ] = None,
    spacing: Annotated[float, typer.Option(help="Sample spacing along the path, m.")] = 5.0,
    prior: Annotated[
        Path | None,
        typer.Option(
            help="Prior DEM: a GeoTIFF (any raster GDAL reads) or NetCDF ('elevation'), any "
            "CRS; default: the embedded site."
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the piecewise-continuous switching.")] = 0,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/plan"),
) -> None:
    """Plan a survey (lawnmower or the paper's piecewise continuous, Eq 10) and report its
    path length, science-centric coverage (Eq 11), centeredness (Eq 12-13) and
    distributedness (Eq 14-16); writes OUT/plan.json and OUT/plan.png."""
    from shapely.geometry import box

    from survey import (
        candidate_points,
        centeredness,
        lawnmower,
        piecewise_continuous,
        plan_distributedness,
        science_centric_coverage,
    )
    from survey.figures import plot_plan
    from terrain import Grid
    from terrain.atomic import atomic_path, ensure_writable_dir

    dem = _read_prior(prior)
    grid = Grid.from_dataarray(dem)
    region = box(*(bounds or grid.bounds))
    if pattern == "lawnmower":
        plan = lawnmower(region, swaths, heading=heading, spacing=spacing, crs=grid.crs)
    elif pattern == "piecewise_continuous":
        plan = piecewise_continuous(
            region, swaths, dem, seed=seed, spacing=spacing, heading=heading, crs=grid.crs
        )
    else:
        raise bad_input("--pattern", pattern, "lawnmower or piecewise_continuous", "")
    out_dir = ensure_writable_dir(out)
    centre = np.array(region.centroid.coords[0])
    candidates = candidate_points(region, spacing)
    per_swath, beta = plan_distributedness(plan)
    metrics = {
        "path_length_m": plan.path_length,
        "n_samples": int(len(plan.samples)),
        "science_centric_coverage": float(
            science_centric_coverage(plan.samples, candidates, ref=centre)
        ),
        "centeredness_alpha": float(centeredness(plan.samples, ref=centre, region=region)),
        "distributedness_beta": None if np.isnan(beta) else float(beta),
    }
    with atomic_path(out_dir / "plan.json") as tmp:
        tmp.write_text(json.dumps({**plan.to_dict(), "metrics": metrics}))
    png = plot_plan(plan, dem, out_dir / "plan.png")
    table = Table(title=f"{pattern}, {swaths} swaths, heading {plan.heading_deg:.1f} deg")
    table.add_column("metric")
    table.add_column("value", justify="right")
    for k, v in metrics.items():
        table.add_row(k, "undefined (straight swaths)" if v is None else f"{v:.4g}")
    console.print(table)
    console.print(f"wrote {out_dir / 'plan.json'} and {png}")
