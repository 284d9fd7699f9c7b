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


def export_command(
    product: Annotated[
        Path, typer.Argument(help="Terrain product NetCDF (elevation, elevation_std, CRS).")
    ],
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/export"),
    interval: Annotated[float, typer.Option(help="Contour interval, m.")] = 1.0,
    exaggeration: Annotated[
        float, typer.Option(help="Vertical exaggeration of the mesh render.")
    ] = 3.0,
    geojson: Annotated[
        bool, typer.Option(help="Also write the contours as GeoJSON (lon/lat).")
    ] = True,
    mesh: Annotated[bool, typer.Option(help="Write the mesh (PLY, VTP, PNG).")] = True,
) -> None:
    """Export a terrain map: Cloud-Optimized GeoTIFF (elevation + 1-sigma bands), contour
    lines (GeoPackage, GeoJSON) and a mesh with per-vertex 1-sigma (PLY, VTP, PNG render);
    writes them and export_summary.json into --out."""
    from ..export import INDEX_EVERY, write_cog, write_contours, write_mesh

    if not (np.isfinite(interval) and interval > 0):
        raise bad_input("--interval", interval, "a positive contour interval in metres", "")
    if not (np.isfinite(exaggeration) and exaggeration > 0):
        raise bad_input("--exaggeration", exaggeration, "a positive factor", "e.g. 3")
    ds = _open_product(product)
    out_dir = ensure_writable_dir(out)
    summary: dict = {"product": str(product), "seed": ds.attrs.get("seed")}
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
    console.print(f"wrote {out_dir / FILES['summary']}")
