"""``glacimap change``: elevation, volume and mass change between two epochs of a glacier."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console

from terrain.atomic import atomic_path, ensure_writable_dir
from terrain.coregister import stable_mask
from terrain.errors import bad_input
from terrain.grid import Grid
from terrain.volume import _check_density

console = Console()

#: File names written into --out.
FILES = {
    "cog": "dh.tif",
    "netcdf": "change.nc",
    "json": "volume.json",
    "csv": "volume.csv",
    "report": "change_report.html",
}


def read_dem(path: Path, field: str):
    """A glacimap product NetCDF (``elevation``, ``elevation_std``) or a GeoTIFF (band 1
    elevation; a band described ``elevation_std`` is read as its 1-sigma), as a Dataset."""
    import rasterio
    import xarray as xr

    if not path.is_file():
        raise bad_input(field, str(path), "an existing NetCDF or GeoTIFF file", "check the path")
    if path.suffix.lower() in (".nc", ".nc4", ".netcdf"):
        with xr.open_dataset(path) as ds:
            return ds.load()
    try:
        with rasterio.open(path) as src:
            bands = src.read().astype(float)
            if src.nodata is not None and np.isfinite(src.nodata):
                bands[bands == src.nodata] = np.nan
            desc = list(src.descriptions)
            t, crs, tags = src.transform, src.crs, src.tags()
    except rasterio.errors.RasterioIOError as exc:
        raise bad_input(field, str(path), "a raster GDAL can read", str(exc)) from exc
    if crs is None or t.b != 0 or t.d != 0 or t.e >= 0:
        raise bad_input(field, str(path), "a north-up raster with a CRS", "warp it first")
    grid = Grid(t.c, t.f, (t.a, -t.e), bands.shape[1:], crs.to_wkt())
    data = {"elevation": (("y", "x"), bands[0])}
    if "elevation_std" in desc:
        data["elevation_std"] = (("y", "x"), bands[desc.index("elevation_std")])
    attrs = {**tags, **grid.attrs(), "source": str(path)}
    return xr.Dataset(data, coords=grid.coords(), attrs=attrs)


def read_polygons(path: Path, field: str, crs: Any) -> tuple[Any, str]:
    """Polygons of a vector file (GeoPackage, GeoJSON, Shapefile) in ``crs``; a note says
    whether they were reprojected."""
    import pyogrio
    import shapely
    from pyproj import CRS, Transformer

    if not path.is_file():
        raise bad_input(field, str(path), "an existing vector file", "check the path")
    try:
        info = pyogrio.read_info(path)
        _, _, wkb, _ = pyogrio.raw.read(path)
    except Exception as exc:  # pyogrio's DataSourceError and friends
        raise bad_input(field, str(path), "a GeoPackage / GeoJSON GDAL can read", str(exc)) from exc
    geoms = [g for g in shapely.from_wkb(wkb) if g is not None and g.area > 0]
    if not geoms:
        raise bad_input(field, str(path), "at least one polygon", "draw the outline as polygons")
    merged = shapely.union_all(geoms)
    src = CRS.from_user_input(info["crs"]) if info.get("crs") else None
    note = f"{field}: same CRS"
    if src is not None and not src.equals(CRS.from_user_input(crs), ignore_axis_order=True):
        t = Transformer.from_crs(src, CRS.from_user_input(crs), always_xy=True)
        merged = shapely.ops.transform(t.transform, merged)
        note = f"{field}: reprojected from {src.to_string()}"
    return merged, note


def change_command(
    before: Annotated[Path, typer.Argument(help="Earlier DEM: product NetCDF or GeoTIFF.")],
    after: Annotated[Path, typer.Argument(help="Later DEM: product NetCDF or GeoTIFF.")],
    outline: Annotated[Path, typer.Option(help="Glacier outline (GeoPackage / GeoJSON).")],
    stable: Annotated[
        Path | None, typer.Option(help="Stable ground polygons; default: outside the outline.")
    ] = None,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/change"),
    coregister: Annotated[
        bool, typer.Option(help="Co-register AFTER to BEFORE (Nuth & Kaab) on stable ground.")
    ] = True,
    density: Annotated[float, typer.Option(help="Volume-to-mass density, kg m^-3.")] = 850.0,
    density_std: Annotated[float, typer.Option(help="1-sigma of the density.")] = 60.0,
    seed: Annotated[int, typer.Option(help="Seed of the variogram's pair subsample.")] = 0,
) -> None:
    """Elevation change (dh COG with 1-sigma band), volume and mass change with an error
    budget (JSON + CSV) and an HTML report, from two DEMs of the same glacier.

    From files the 1-sigma of the volume change comes from the variogram of dh on stable
    ground (Rolstad 2009 / Hugonnet 2022); the exact GP route needs the fitted GPs
    (terrain.volume_change(..., models=...), see docs/change.md).
    """
    import shapely

    from terrain import difference, volume_change

    from ..change_report import (
        band_sigma_from,
        hypsometric_profile,
        write_change_cog,
        write_change_report,
        write_volume_tables,
    )
    from ..export._files import staged_folder

    t0 = time.perf_counter()
    b = read_dem(before, "BEFORE")
    a = read_dem(after, "AFTER")
    crs = b.attrs["crs_wkt"]
    glacier, note_o = read_polygons(outline, "--outline", crs)
    stable_geom, note_s = (None, "")
    if stable is not None:
        stable_geom, note_s = read_polygons(stable, "--stable", crs)
    # every check before anything is written: bad input leaves --out untouched
    _check_density((density, density_std))
    diff = difference(b, a, coregister=coregister, stable=stable_geom, outline=glacier)
    grid = Grid.from_dataarray(diff)
    mask = None if stable_geom is None else stable_mask(grid, stable_geom)[0]
    vc = volume_change(diff, glacier, (density, density_std), stable=mask, seed=seed)
    profile = hypsometric_profile(diff, glacier, band_sigma=band_sigma_from(vc, grid))
    out_dir = ensure_writable_dir(out)
    with staged_folder(out_dir) as tmp:
        write_change_cog(diff, tmp / FILES["cog"])
        with atomic_path(tmp / FILES["netcdf"]) as nc:
            diff.to_netcdf(nc, engine="scipy")
        extra = {
            "inputs": {"before": str(before), "after": str(after), "outline": str(outline)},
            "notes": [n for n in (note_o, note_s, diff.attrs["reprojection"]) if n],
            "coregistration": json.loads(diff.attrs["coregistration"])
            if diff.attrs["coregistration"] != "none"
            else None,
            "hypsometry": profile,
            "outline_wkt": shapely.to_wkt(glacier, rounding_precision=3),
        }
        write_volume_tables(vc, tmp / FILES["json"], tmp / FILES["csv"], **extra)
        write_change_report(tmp / FILES["report"], diff, vc, glacier, profile)
    console.print(
        f"dV = {vc.volume_m3:,.0f} +- {vc.volume_std_m3:,.0f} m^3 over {vc.area_m2:,.0f} m^2 "
        f"(mean dh {vc.mean_dh_m:+.3f} +- {vc.mean_dh_std_m:.3f} m; {vc.method}); "
        f"dM = {vc.mass_gt:.6f} +- {vc.mass_std_kg / 1e12:.6f} Gt"
    )
    console.print(
        f"wrote {', '.join(FILES.values())} in {out_dir} ({time.perf_counter() - t0:.1f} s)"
    )
