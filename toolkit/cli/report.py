"""``glacimap report``: rebuild the HTML accuracy report of a run folder."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

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
        import numpy as np

        data = np.atleast_1d(np.genfromtxt(samples, delimiter=",", names=True, dtype=float))
        if not {"x", "y"} <= set(data.dtype.names or ()):
            raise bad_input(samples.name, data.dtype.names, "columns x, y", "rename the header")
        out["samples"] = np.column_stack([data["x"], data["y"]])
    return out


def report_command(
    run_dir: Annotated[
        Path, typer.Argument(help="Run folder with certificate.json and product.nc.")
    ],
    out: Annotated[
        Path | None, typer.Option(help="Output HTML (default RUN_DIR/report.html).")
    ] = None,
    title: Annotated[str, typer.Option(help="Title of the report.")] = (
        "glacimap accuracy certificate"
    ),
) -> None:
    """Rebuild RUN_DIR/report.html, a self-contained HTML accuracy report, from
    RUN_DIR/certificate.json and the product NetCDF (product.nc, else reconstruction.nc);
    adds the error map and calibration curve if truth.nc is there, the trajectory from
    trajectory.npz, coverage metrics from coverage.json and sample locations from samples.csv."""
    from ..report import write_report

    if not run_dir.is_dir():
        raise bad_input("RUN_DIR", str(run_dir), "an existing folder", "check the path")
    cert = run_dir / RUN_FILES["certificate"]
    if not cert.is_file():
        fix = f"run glacimap certify DEM CHECKPOINTS --out {cert}"
        raise bad_input("RUN_DIR", str(run_dir), f"a folder with {cert.name}", fix)
    product = next((run_dir / n for n in RUN_FILES["product"] if (run_dir / n).is_file()), None)
    if product is None:
        names = " or ".join(RUN_FILES["product"])
        raise bad_input("RUN_DIR", str(run_dir), f"a folder with {names}", "add the product")
    target = out if out is not None else run_dir / RUN_FILES["report"]
    with console.status("drawing the report..."):
        path = write_report(
            target,
            product=_open(product),
            certificate=cert,
            title=title,
            **_optional(run_dir),
        )
    console.print(f"wrote {path}")
