"""``glacimap change``: elevation, volume and mass change between two epochs of a glacier."""

from __future__ import annotations

import dataclasses
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
    from rasterio.crs import CRS as RioCRS

    from terrain.vertical_datum import split_vertical

    horizontal, datum = split_vertical(crs.to_wkt())  # a compound CRS states the heights
    crs = RioCRS.from_wkt(horizontal.to_wkt())
    if datum is not None:
        tags = {**tags, "height_datum": datum}
    data = {"elevation": (("y", "x"), bands[0])}
    if "elevation_std" in desc:
        data["elevation_std"] = (("y", "x"), bands[desc.index("elevation_std")])
    if crs.is_geographic:  # SRTM, GLO-30...: terrain.difference compares the two in metres
        ny, nx = bands.shape[1:]
        y, x = t.f + (np.arange(ny) + 0.5) * t.e, t.c + (np.arange(nx) + 0.5) * t.a
        attrs = {"crs_wkt": crs.to_wkt(), "crs": crs.to_string(), "resolution": (t.a, -t.e)}
        return xr.Dataset(
            data, coords={"y": y, "x": x}, attrs={**tags, **attrs, "source": str(path)}
        )
    grid = Grid(t.c, t.f, (t.a, -t.e), bands.shape[1:], crs.to_wkt())
    attrs = {**tags, **grid.attrs(), "source": str(path)}
    return xr.Dataset(data, coords=grid.coords(), attrs=attrs)


def read_polygons(path: Path, field: str, crs: Any, where: str | None = None) -> tuple[Any, str]:
    """Polygons of a vector file (GeoPackage, GeoJSON, Shapefile) merged, in ``crs``; a note
    says whether they were reprojected (:func:`toolkit.vector_io.read_geometries`); ``where``
    an OGR SQL clause selecting the features (an inventory's one glacier)."""
    import shapely

    from ..vector_io import read_geometries

    geoms, note = read_geometries(path, field, crs, where=where)
    geoms = [g for g in geoms if g.area > 0]
    if not geoms:
        raise bad_input(field, str(path), "at least one polygon", "draw the outline as polygons")
    return shapely.union_all(geoms), note


def change_command(
    before: Annotated[
        Path, typer.Argument(help="Earlier DEM: a glacimap product folder, NetCDF or GeoTIFF.")
    ],
    after: Annotated[
        Path, typer.Argument(help="Later DEM: a glacimap product folder, NetCDF or GeoTIFF.")
    ],
    outline: Annotated[
        Path, typer.Option(help="Glacier outline(s) (GeoPackage, GeoJSON, Shapefile...).")
    ],
    outline_where: Annotated[
        str | None,
        typer.Option(
            help="Keep the outline features this OGR SQL WHERE clause selects, e.g. "
            "\"RGIId = 'RGI60-07.01482'\" for one glacier of an inventory file."
        ),
    ] = None,
    per_glacier: Annotated[
        str | None,
        typer.Option(
            help="The outline file's ID attribute (e.g. RGIId): also each glacier's volume "
            "change and mass balance, one row each in glaciers.csv (stable ground: outside "
            "every glacier, or --stable)."
        ),
    ] = None,
    clip_outline: Annotated[
        bool,
        typer.Option(
            help="Clip the outline to the two DEMs' common grid (said, with the area cut). "
            "Without it an outline reaching beyond the grid is refused: the volume of the "
            "part the DEMs cover is not the glacier's."
        ),
    ] = False,
    stable: Annotated[
        Path | None, typer.Option(help="Stable ground polygons; default: outside the outline.")
    ] = None,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/change"),
    coregister: Annotated[
        bool | None,
        typer.Option(
            help="Co-register AFTER to BEFORE (Nuth & Kaab) on stable ground. Default: off on "
            "the GP route (the maps' shared offsets are in the 1-sigma), on otherwise."
        ),
    ] = None,
    samples_before: Annotated[
        Path | None,
        typer.Option(help="Samples CSV of BEFORE (default: samples.csv beside its map)."),
    ] = None,
    samples_after: Annotated[
        Path | None,
        typer.Option(help="Samples CSV of AFTER (default: samples.csv beside its map)."),
    ] = None,
    prior_before: Annotated[
        Path | None,
        typer.Option(help="Prior DEM of BEFORE's mean, if not where the product recorded it."),
    ] = None,
    prior_after: Annotated[
        Path | None,
        typer.Option(help="Prior DEM of AFTER's mean, if not where the product recorded it."),
    ] = None,
    heights_before: Annotated[
        str | None,
        typer.Option(
            help="What BEFORE's heights are above, when it does not say: ellipsoidal, egm96 "
            "(SRTM, NASADEM, ASTER), egm2008 (GLO-30), or a national vertical CRS "
            "(EPSG:5941 NN2000...). Default: the DEM's own statement "
            "(a glacimap product: ellipsoidal; a compound CRS)."
        ),
    ] = None,
    heights_after: Annotated[
        str | None, typer.Option(help="The same for AFTER; it is carried to BEFORE's datum.")
    ] = None,
    dates: Annotated[
        tuple[str, str] | None,
        typer.Option(
            help="BEFORE's and AFTER's survey dates (ISO, e.g. --dates 2015-08-01 2024-08-20): "
            "the mass balance per year (m w.e. a^-1) and dh/dt beside the period's. Default: "
            "the products' survey_date (maps of GNSS logs record it)."
        ),
    ] = None,
    density: Annotated[float, typer.Option(help="Volume-to-mass density, kg m^-3.")] = 850.0,
    density_std: Annotated[float, typer.Option(help="1-sigma of the density.")] = 60.0,
    seed: Annotated[int, typer.Option(help="Seed of the variogram's pair subsample.")] = 0,
) -> None:
    """Elevation change (dh COG with 1-sigma band), volume and mass change with an error
    budget (JSON + CSV) and an HTML report, from two DEMs of the same glacier.

    Route of the volume 1-sigma, stated in the output (``route``, ``route_reason``):
    gp_structure when both inputs are glacimap products with their samples (a product folder
    of run / process holds samples.csv; else --samples-before/--samples-after): each map's
    GP is refitted on its samples at its recorded kernel, nugget and mean, checked to
    reproduce the map, and its posterior covariance integrated over the outline plus each
    survey's shared offset (as terrain.volume_change(..., models=...)); otherwise the
    variogram of dh on stable ground (Rolstad 2009 / Hugonnet 2022). See docs/change.md.
    """
    import shapely

    from terrain import difference, volume_change
    from terrain.dem_projection import change_crs
    from terrain.mass_balance import mass_balance, survey_years
    from terrain.outline_cover import clip_outline as clip_to_grid

    from ..change_inputs import locate_product
    from ..change_report import (
        band_sigma_from,
        epoch_breaklines,
        hypsometric_profile,
        write_change_cog,
        write_change_report,
        write_volume_tables,
    )
    from ..export._files import staged_folder

    t0 = time.perf_counter()
    where_b = locate_product(before, samples_before, "BEFORE")
    where_a = locate_product(after, samples_after, "AFTER")
    b = read_dem(where_b.raster, "BEFORE")
    a = read_dem(where_a.raster, "AFTER")
    a, note_h = same_heights(b, a, heights_before, heights_after)  # one vertical datum
    crs, _ = change_crs(b, a)  # the CRS dh is mapped in (a DEM in degrees is projected)
    inventory = None
    if per_glacier is None:
        glacier, note_o = read_polygons(outline, "--outline", crs, where=outline_where)
    else:  # each feature with its ID; the glacier the union of those with an area
        from ..vector_io import read_features

        geoms, ids, note_o = read_features(outline, "--outline", crs, outline_where, per_glacier)
        inventory = [(i, g) for i, g in zip(ids, geoms, strict=True) if g.area > 0]
        if not inventory:
            raise bad_input("--outline", str(outline), "at least one polygon", "draw them")
        glacier = shapely.union_all([g for _, g in inventory])
    stable_geom, note_s = (None, "")
    if stable is not None:
        stable_geom, note_s = read_polygons(stable, "--stable", crs)
    # every check before anything is written: bad input leaves --out untouched
    _check_density((density, density_std))
    if dates is not None:
        survey_years(dates)
    models, route_reason, gp_notes = _gp_route(b, a, where_b, where_a, prior_before, prior_after)
    route = "gp_structure" if models is not None else "variogram"
    if coregister is None:
        coregister = models is None
        route_reason += (
            "; not co-registered (default on the GP route: the shared offsets are in the "
            "1-sigma, and stable ground next to a GP map absorbs part of the thinning)"
            if models is not None
            else "; co-registered on stable ground (default on the variogram route)"
        )
    diff = difference(b, a, coregister=coregister, stable=stable_geom, outline=glacier)
    grid = Grid.from_dataarray(diff)
    if clip_outline:  # said in the notes: the volume is then the covered part's
        glacier, cut = clip_to_grid(glacier, grid, "--outline")
        note_o = (
            f"{note_o}; clipped to the DEMs' common grid: {cut['outside_grid_m2']:,.0f} of "
            f"{cut['area_m2']:,.0f} m^2 ({100 * cut['outside_share']:.1f} %) cut"
        )
    mask = None if stable_geom is None else stable_mask(grid, stable_geom)[0]
    vc = volume_change(diff, glacier, (density, density_std), models=models, stable=mask, seed=seed)
    note = f"{vc.details['method_note']}. Route {route_reason}"  # the HTML report shows it
    vc = dataclasses.replace(vc, details={**vc.details, "method_note": note})
    dates, note_d = _survey_dates(dates, b.attrs, a.attrs)
    balance = mass_balance(vc, dates)  # m w.e. (per year with dates)
    balance["note"] += note_d
    glaciers = None
    if inventory is not None:  # one volume per glacier, the same stable ground for all
        from ..change_glaciers import glacier_rows

        rows, note_g = glacier_rows(
            diff, [g for _, g in inventory], [i for i, _ in inventory],
            density=(density, density_std), models=models, stable=mask, seed=seed,
            dates=dates, clip=clip_outline,
        )  # fmt: skip
        glaciers = {"id_attribute": per_glacier, "note": note_g, "rows": rows}
    profile = hypsometric_profile(diff, glacier, band_sigma=band_sigma_from(vc, grid))
    lines = epoch_breaklines(b.attrs, a.attrs, models)  # the cliffs each map was fitted with
    horizontal = _horizontal_note(b.attrs, a.attrs, models is not None)
    out_dir = ensure_writable_dir(out)
    with staged_folder(out_dir) as tmp:
        write_change_cog(diff, tmp / FILES["cog"])
        with atomic_path(tmp / FILES["netcdf"]) as nc:
            diff.to_netcdf(nc, engine="scipy")
        extra = {
            "route": route,
            "route_reason": route_reason,
            "gp_rebuild": gp_notes,
            "inputs": {
                "before": str(before),
                "after": str(after),
                "outline": str(outline),
                "samples_before": None if where_b.samples is None else str(where_b.samples),
                "samples_after": None if where_a.samples is None else str(where_a.samples),
            },
            "notes": [
                n for n in (note_h, note_o, note_s, diff.attrs["reprojection"], horizontal) if n
            ],
            "coregistration": json.loads(diff.attrs["coregistration"])
            if diff.attrs["coregistration"] != "none"
            else None,
            "hypsometry": profile,
            "outline_wkt": shapely.to_wkt(glacier, rounding_precision=3),
            "breaklines": lines or None,
            "mass_balance": balance,
            **({"glaciers": glaciers} if glaciers is not None else {}),
        }
        write_volume_tables(vc, tmp / FILES["json"], tmp / FILES["csv"], **extra)
        write_change_report(
            tmp / FILES["report"], diff, vc, glacier, profile, breaklines=lines, balance=balance
        )
        if glaciers is not None:
            from ..change_glaciers import write_glacier_table

            write_glacier_table(glaciers["rows"], tmp / "glaciers.csv")
    if note_h:
        console.print(f"[yellow]heights:[/] {note_h}")
    console.print(f"route: {route} ({route_reason})")
    if horizontal:
        console.print(f"[yellow]note:[/] {horizontal}")
    for name, at in (vc.details.get("along_track") or {}).items():
        if isinstance(at, dict) and "status" in at:  # included, or said why not: never silent
            console.print(f"along-track term, {name}: {at['status']}")
    console.print(
        f"dV = {vc.volume_m3:,.0f} +- {vc.volume_std_m3:,.0f} m^3 over {vc.area_m2:,.0f} m^2 "
        f"(mean dh {vc.mean_dh_m:+.3f} +- {vc.mean_dh_std_m:.3f} m; {vc.method}); "
        f"dM = {vc.mass_gt:.6f} +- {vc.mass_std_kg / 1e12:.6f} Gt"
    )
    console.print(f"mass balance: {balance['note']}")
    if glaciers is not None:
        console.print(f"per glacier ({per_glacier}): {glaciers['note']}; glaciers.csv")
    console.print(
        f"wrote {', '.join(FILES.values())} in {out_dir} ({time.perf_counter() - t0:.1f} s)"
    )


def _survey_dates(dates: Any, before: dict, after: dict) -> tuple[Any, str]:
    """``--dates``, else both products' ``survey_date`` (a GNSS log's map records it), and
    where they came from."""
    if dates is not None:
        return dates, " (--dates)"
    found = (before.get("survey_date"), after.get("survey_date"))
    if not all(found):
        return None, ""
    from terrain.errors import InputError
    from terrain.mass_balance import survey_years

    try:
        survey_years(found)
    except InputError:  # the same day, or AFTER surveyed first: said, no rate
        return None, f" (the products' survey dates {found[0]} -> {found[1]}: pass --dates)"
    return found, " (the products' survey_date)"


def same_heights(b: Any, a: Any, given_b: str | None, given_a: str | None) -> tuple[Any, str]:
    """AFTER in BEFORE's vertical datum, and in words what was done.

    Each DEM's datum is what it states (:func:`terrain.vertical_datum.dem_height_datum`: a
    glacimap product is ellipsoidal, a compound CRS names its geoid), else the option given
    (an option contradicting a DEM's own statement is an error). When both are known and
    differ, AFTER's elevation gets ``N_after - N_before`` (the geoids' undulations at its
    cells; 0 for the ellipsoid): a DEM in EGM96 heights against a glacimap map differs by
    N, tens of metres, which a change without co-registration would read as thinning."""
    from terrain.vertical_datum import (
        datum_words,
        dem_height_datum,
        product_in_datum,
        stated_or_given,
    )

    db, da = (
        stated_or_given(dem_height_datum(ds.attrs), given, f"--heights-{name}", name.upper())
        for ds, given, name in ((b, given_b, "before"), (a, given_a, "after"))
    )
    if db is None and da is None:
        return a, ""  # both as stored: one datum, as every change before
    if db is None or da is None:
        known, unknown = ("BEFORE", "AFTER") if da is None else ("AFTER", "BEFORE")
        return a, (
            f"{unknown} states no vertical datum: taken as {known}'s ({db or da}); if it is "
            f"not, pass --heights-{unknown.lower()} (SRTM, NASADEM, ASTER: egm96; GLO-30: "
            "egm2008; glacimap maps, ArcticDEM, REMA: ellipsoidal)"
        )
    if db == da:
        return a, f"both DEMs in {db} heights"
    # h = H + N at AFTER's own cells: into BEFORE's datum (terrain.vertical_datum)
    out, _ = product_in_datum(a.assign_attrs(height_datum=da), db, "--heights-after")
    shift = (out["elevation"] - a["elevation"]).values
    return out, (
        f"AFTER's heights above {datum_words(da)} carried to BEFORE's ({datum_words(db)}): "
        f"{float(np.nanmean(shift)):+.2f} m on average ({float(np.nanmin(shift)):+.2f} to "
        f"{float(np.nanmax(shift)):+.2f} m)"
    )


def _horizontal_note(before: Any, after: Any, gp_route: bool) -> str:
    """What the volume's 1-sigma leaves out when a map states its samples' horizontal
    1-sigma (``glacimap reconstruct --horizontal-sd``: digitised contours); "" otherwise.
    Each cell's dh 1-sigma carries it (the maps' ``elevation_std``); the GP route's volume
    1-sigma integrates the GPs' covariance and does not (how a contour's shift correlates
    along it is not modelled); the variogram route measures it on stable ground."""
    stated = [
        f"the {name} map's {float(attrs['samples_horizontal_std_m']):g} m"
        for name, attrs in (("before", before), ("after", after))
        if attrs.get("samples_horizontal_std_m")
    ]
    if not stated or not gp_route:
        return ""
    return (
        f"{' and '.join(stated)} samples' horizontal 1-sigma (through the slope) is in each "
        "cell's dh 1-sigma but not in the volume's on the GP route: its correlation along "
        "the contours is not modelled; the variogram route (no --samples-*) measures it on "
        "stable ground"
    )


def _gp_route(b, a, where_b, where_a, prior_b, prior_a) -> tuple[Any, str, dict[str, str]]:
    """(the two rebuilt GPs or None, why this route, per-epoch rebuild notes)."""
    from ..change_inputs import rebuild_gp

    if where_b.samples is None and where_a.samples is None:
        why = "variogram: neither input comes with its samples (no product folder with "
        return None, why + "samples.csv, no --samples-before/--samples-after)", {}
    notes, gps = {}, []
    with console.status("rebuilding the two maps' GPs from their samples..."):
        for name, ds, where, prior in (
            ("before", b, where_b, prior_b),
            ("after", a, where_a, prior_a),
        ):
            gp, note = rebuild_gp(ds, where, prior)
            notes[name] = note
            gps.append(gp)
    if any(g is None for g in gps):
        bad = "; ".join(
            f"{k}: {v}" for (k, v), g in zip(notes.items(), gps, strict=True) if g is None
        )
        return None, f"variogram: the GP route needs both maps' GPs ({bad})", notes
    why = (
        "gp_structure: both inputs are glacimap GP products with their samples; their GPs "
        "were rebuilt at the recorded hyperparameters and reproduce the maps"
    )
    return tuple(gps), why, notes
