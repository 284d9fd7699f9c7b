"""``glacimap report``: rebuild the HTML accuracy report of a run folder."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape

from terrain.errors import bad_input

console = Console()

#: What ``glacimap report RUN_DIR`` reads from RUN_DIR (optional ones may be absent).
RUN_FILES = {
    "certificate": "certificate.json",  # required: glacimap certify --out RUN_DIR/certificate.json
    "product": ("product.nc", "reconstruction.nc"),  # required: the first that exists
    "truth": "truth.nc",  # optional: true DEM on the product grid (DataArray or 'elevation')
    "coverage": "coverage.json",  # optional: {"metric name": value, ...}
    "trajectory": "trajectory.npz",  # optional: xy_est (n, 2)[, xy_true, cov_xy, landmarks_xy]
    "samples": "samples.csv",  # optional: header with x, y (sample locations, m)
    "report": "report.html",  # written
}


def _open(path: Path):
    import xarray as xr

    try:
        with xr.open_dataset(path) as ds:
            return ds.load()
    except (OSError, ValueError, TypeError) as exc:
        raise bad_input(path.name, str(path), "a readable NetCDF file", str(exc)) from exc


def _optional(run_dir: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    truth = run_dir / RUN_FILES["truth"]
    if truth.is_file():
        ds = _open(truth)
        names = list(ds.data_vars)
        out["truth"] = ds["elevation"] if "elevation" in names else ds[names[0]]
    coverage = run_dir / RUN_FILES["coverage"]
    if coverage.is_file():
        try:
            data = json.loads(coverage.read_text(encoding="utf-8"))
        except ValueError as exc:
            raise bad_input(coverage.name, str(coverage), "JSON", str(exc)) from exc
        if not isinstance(data, dict):
            raise bad_input(coverage.name, type(data).__name__, "a JSON object", "")
        out["coverage"] = data
    traj = run_dir / RUN_FILES["trajectory"]
    if traj.is_file():
        import numpy as np

        with np.load(traj) as npz:
            out["trajectory"] = {k: npz[k] for k in npz.files}
    samples = run_dir / RUN_FILES["samples"]
    if samples.is_file():
        out.update(_sample_points(samples))
    return out


def _sample_points(path: Path) -> dict[str, Any]:
    """The sample locations to draw, read like every point table (any delimiter, header
    aliases); a file that cannot be drawn (another layout, lon/lat) is said and skipped:
    the samples are decoration of the report, not what it certifies."""
    from terrain.errors import InputError

    from ..certify_io import read_checkpoints

    try:
        table = read_checkpoints(path)
    except InputError as exc:
        console.print(f"[yellow]note:[/] {path.name} not drawn: {escape(str(exc))}", soft_wrap=True)
        return {}
    if table.crs is not None and table.crs.is_geographic:
        console.print(f"[yellow]note:[/] {path.name} not drawn: lon/lat, not the map's CRS")
        return {}
    keep = ~table.nan_rows()
    return {"samples": table.xy[keep]}


def _certified_dem(run_dir: Path, cert_path: Path, dem: Path | None) -> Path:
    """The DEM to draw: --dem, else the run's product, else the file the certificate names
    (``glacimap certify`` of a surveyor's own GeoTIFF), found as given, in RUN_DIR or beside
    the certificate; a named file must still have the bytes that were certified."""
    from ..provenance import file_sha256

    if dem is not None:
        if not dem.is_file():
            raise bad_input("--dem", str(dem), "an existing GeoTIFF or NetCDF DEM", "check it")
        return dem
    product = next((run_dir / n for n in RUN_FILES["product"] if (run_dir / n).is_file()), None)
    if product is not None:
        return product
    try:
        named = json.loads(cert_path.read_text(encoding="utf-8")).get("dem") or {}
    except (ValueError, AttributeError) as exc:
        raise bad_input(cert_path.name, str(cert_path), "certificate JSON", str(exc)) from exc
    name, where = named.get("path") or named.get("name"), []
    if name:
        where = [Path(name), run_dir / Path(name).name, cert_path.parent / Path(name).name]
    found = next((p for p in where if p.is_file()), None)
    if found is None:
        names = " or ".join(RUN_FILES["product"])
        raise bad_input(
            "RUN_DIR",
            str(run_dir),
            f"a folder with {names}, or the certified DEM {name!r} in reach",
            "pass the certified DEM: glacimap report RUN_DIR --dem DEM.tif",
        )
    digest = file_sha256(found)
    if named.get("sha256") not in (None, digest):
        raise bad_input(
            "DEM",
            found.name,  # the name, not a long path the message would cut
            f"the file certified (sha256 {named['sha256'][:12]}...) in {found.parent}",
            "re-run glacimap certify on this DEM, or pass the certified one with --dem",
        )
    return found


def report_command(
    run_dir: Annotated[
        Path,
        typer.Argument(
            help="Run folder with certificate.json (and product.nc), or a certificate JSON."
        ),
    ],
    out: Annotated[
        Path | None, typer.Option(help="Output HTML (default RUN_DIR/report.html).")
    ] = None,
    dem: Annotated[
        Path | None,
        typer.Option(
            help="The certified DEM (default: the run's product, else the certified file)."
        ),
    ] = None,
    title: Annotated[str, typer.Option(help="Title of the report.")] = (
        "glacimap accuracy certificate"
    ),
) -> None:
    """Rebuild RUN_DIR/report.html, a self-contained HTML accuracy report, from
    RUN_DIR/certificate.json (or the certificate JSON given as RUN_DIR) and the DEM: --dem,
    else the product NetCDF (product.nc, reconstruction.nc), else the DEM file the
    certificate names (a surveyor's own GeoTIFF certified with glacimap certify); adds the
    error map and calibration curve if truth.nc is there, the trajectory from
    trajectory.npz, coverage metrics from coverage.json and sample locations from samples.csv."""
    from ..report import write_report

    if run_dir.is_file() and run_dir.suffix.lower() == ".json":
        cert, run_dir = run_dir, run_dir.parent
    else:
        if not run_dir.is_dir():
            raise bad_input("RUN_DIR", str(run_dir), "an existing folder", "check the path")
        cert = run_dir / RUN_FILES["certificate"]
    if not cert.is_file():
        fix = f"run glacimap certify DEM CHECKPOINTS --out {cert}"
        raise bad_input("RUN_DIR", str(run_dir), f"a folder with {cert.name}", fix)
    product = _certified_dem(run_dir, cert, dem)
    target = out if out is not None else run_dir / RUN_FILES["report"]
    with console.status("drawing the report..."):
        path = write_report(
            target,
            product=product if product.suffix.lower() != ".nc" else _open(product),
            certificate=cert,
            title=title,
            **_optional(run_dir),
        )
    console.print(f"wrote {path}")
