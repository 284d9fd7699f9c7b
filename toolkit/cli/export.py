"""``glacimap export``: GIS and mesh products from a terrain map NetCDF."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console

from terrain.atomic import atomic_path, ensure_writable_dir
from terrain.errors import bad_input

console = Console()

#: File names written into --out.
FILES = {
    "cog": "elevation.tif",
    "gpkg": "contours.gpkg",
    "geojson": "contours.geojson",
    "ply": "mesh.ply",
    "vtp": "mesh.vtp",
    "png": "mesh.png",
    "summary": "export_summary.json",
}


def _open_product(path: Path):
    """Load a terrain product NetCDF (``glacimap reconstruct`` output) into memory."""
    import xarray as xr

    if not path.is_file():
        raise bad_input("PRODUCT", str(path), "an existing NetCDF file", "check the path")
    try:
        with xr.open_dataset(path) as ds:
            return ds.load()
    except (OSError, ValueError, TypeError) as exc:
        raise bad_input(
            "PRODUCT",
            str(path),
            "a NetCDF terrain product (glacimap reconstruct's reconstruction.nc)",
            f"check the file ({exc})",
        ) from exc


def _interval(product: Path, given: float | None) -> tuple[float, str]:
    """The contour interval (m) and where it comes from: ``--interval``, else the
    ``contour_interval`` of the ``certificate.json`` beside ``product`` (``certified_m``, or
    ``uncertified_m`` from the held-out RMSE and the shared offset), else 1 m, said to be
    uncertified. Contours finer than the map's accuracy draw noise as terrain."""
    if given is not None:
        return float(given), f"{given:g} m as given (--interval)"
    cert_path = product.parent / "certificate.json"
    if cert_path.is_file():
        try:
            ci = json.loads(cert_path.read_text()).get("contour_interval") or {}
        except (OSError, ValueError):
            ci = {}
        if ci.get("certified_m"):
            return float(ci["certified_m"]), (
                f"{ci['certified_m']:g} m, certified ({cert_path.name}: {ci.get('how', '')})"
            )
        if ci.get("uncertified_m"):
            return float(ci["uncertified_m"]), (
                f"{ci['uncertified_m']:g} m, from {cert_path.name} (not certified: no checkpoints)"
            )
    return 1.0, (
        "1 m, not certified: no certificate.json with a contour interval beside PRODUCT "
        "(pass --interval, or certify the map with glacimap certify)"
    )


def export_command(
    product: Annotated[
        Path, typer.Argument(help="Terrain product NetCDF (elevation, elevation_std, CRS).")
    ],
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/export"),
    interval: Annotated[
        float | None,
        typer.Option(
            help="Contour interval, m. Default: the interval the certificate.json beside "
            "PRODUCT states (certified, or uncertified from the held-out RMSE), else 1 m."
        ),
    ] = None,
    exaggeration: Annotated[
        float, typer.Option(help="Vertical exaggeration of the mesh render.")
    ] = 3.0,
    geojson: Annotated[
        bool, typer.Option(help="Also write the contours as GeoJSON (lon/lat).")
    ] = True,
    mesh: Annotated[bool, typer.Option(help="Write the mesh (PLY, VTP, PNG).")] = True,
    heights: Annotated[
        str | None,
        typer.Option(
            help="Write heights above: ellipsoidal, egm96 (SRTM's, most maps' sea level) or "
            "egm2008 (GLO-30), or a national vertical CRS (EPSG:5941 NN2000...). Default: as "
            "the product is (glacimap maps: ellipsoidal)."
        ),
    ] = None,
) -> None:
    """Export a terrain map: Cloud-Optimized GeoTIFF (elevation + 1-sigma bands), contour
    lines (GeoPackage, GeoJSON) and a mesh with per-vertex 1-sigma (PLY, VTP, PNG render);
    writes them and export_summary.json into --out."""
    from ..export import INDEX_EVERY, write_cog, write_contours, write_mesh

    interval, basis = _interval(product, interval)
    if not (np.isfinite(interval) and interval > 0):
        raise bad_input("--interval", interval, "a positive contour interval in metres", "")
    if not (np.isfinite(exaggeration) and exaggeration > 0):
        raise bad_input("--exaggeration", exaggeration, "a positive factor", "e.g. 3")
    if heights is not None:  # a bad name fails before the product is read
        from terrain.vertical_datum import height_datum_option

        heights = height_datum_option(heights, "--heights")
    ds = _open_product(product)
    heights_note = None
    if heights is not None:  # every layer in that datum (terrain.vertical_datum)
        from terrain.vertical_datum import product_in_datum

        ds, heights_note = product_in_datum(ds, heights)
    out_dir = ensure_writable_dir(out)
    summary: dict = {"product": str(product), "seed": ds.attrs.get("seed")}
    if heights_note:
        summary["heights"] = heights_note
    summary["contour_interval_basis"] = basis
    with console.status("writing the Cloud-Optimized GeoTIFF..."):
        summary["cog"] = str(write_cog(ds, out_dir / FILES["cog"]))
    with console.status("tracing contours..."):
        summary["contours"] = write_contours(
            ds,
            out_dir / FILES["gpkg"],
            interval,
            out_dir / FILES["geojson"] if geojson else None,
        )
    if mesh:
        with console.status("meshing and rendering..."):
            summary["mesh"] = write_mesh(
                ds,
                out_dir / FILES["ply"],
                out_dir / FILES["vtp"],
                out_dir / FILES["png"],
                exaggeration=exaggeration,
            )
    if isinstance(summary["seed"], np.generic):
        summary["seed"] = summary["seed"].item()
    with atomic_path(out_dir / FILES["summary"]) as tmp:
        tmp.write_text(json.dumps(summary, indent=2, default=str))
    c = summary["contours"]
    console.print(f"wrote {summary['cog']} (bands elevation, elevation_std)")
    console.print(
        f"wrote {c['lines']} contour lines on {c['levels']} levels every {c['interval']:g} m "
        f"({c['index_lines']} index contours, every {INDEX_EVERY * c['interval']:g} m): "
        + ", ".join(c["paths"])
    )
    if mesh:
        m = summary["mesh"]
        console.print(
            f"wrote a mesh of {m['vertices']} vertices, {m['triangles']} triangles "
            f"({m['dropped_cells']} NaN cells dropped, origin {m['origin']}): "
            + ", ".join(m["paths"])
        )
    console.print(f"heights: {c['vertical_datum']}")
    if heights_note:
        console.print(f"heights: {heights_note}")
    console.print(f"contour interval: {basis}")
    console.print(f"wrote {out_dir / FILES['summary']}")
