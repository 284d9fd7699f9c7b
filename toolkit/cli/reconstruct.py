"""``glacimap reconstruct``: a terrain map with 1-sigma from elevation samples, or the demo."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from terrain import ElevationSamples, Grid
from terrain.atomic import atomic_path, ensure_writable_dir
from terrain.errors import bad_input

console = Console()


def _read_samples_csv(path: Path, crs: str) -> ElevationSamples:
    """CSV with a header naming x, y, z and optionally z_var (metres, m^2)."""
    if not path.is_file():
        raise bad_input("SAMPLES", str(path), "an existing CSV file", "check the path")
    data = np.genfromtxt(path, delimiter=",", names=True, dtype=float, encoding="utf-8")
    names = data.dtype.names or ()
    missing = [c for c in ("x", "y", "z") if c not in names]
    if missing:
        raise bad_input(
            f"{path.name} columns",
            list(names),
            f"columns x, y, z[, z_var]; missing {missing}",
            "rename the header",
        )
    data = np.atleast_1d(data)
    z_var = data["z_var"] if "z_var" in names else 0.0
    return ElevationSamples(np.column_stack([data["x"], data["y"]]), data["z"], z_var, crs=crs)


def _print_demo(result) -> None:
    table = Table(title=f"Fig. 5 comparison on the default site (seed {result.seed})")
    table.add_column("method", no_wrap=True)
    for col in ("RMSE m", "hull m", "cover", "in 95%", "in 68%", "sec"):
        table.add_column(col, justify="right", no_wrap=True)
    names = {
        "gp_satellite": "GP + satellite prior",
        "gp_constant": "GP, constant mean",
        "delaunay": "Delaunay linear",
    }
    for key, label in names.items():
        m = result.metrics[key]
        cov95 = f"{100 * m['coverage_95']:.1f} %" if "coverage_95" in m else "—"
        cov68 = f"{100 * m['coverage_68']:.1f} %" if "coverage_68" in m else "—"
        table.add_row(
            label,
            f"{m['rmse']:.3f}",
            f"{m['rmse_on_delaunay_hull']:.3f}",
            f"{100 * m['covered_fraction']:.1f} %",
            cov95,
            cov68,
            f"{result.timings[key]:.1f}",
        )
    console.print(table)
    console.print(
        f"{result.samples.n} landmarks ({result.n_rejected} candidates outside the site "
        f"redrawn, {result.samples.n_merged} duplicates merged); truth grid "
        f"{result.truth.shape[0]} x {result.truth.shape[1]} cells."
    )


def reconstruct(
    samples: Annotated[
        Path | None, typer.Argument(help="CSV with columns x, y, z[, z_var] (m, m^2).")
    ] = None,
    demo: Annotated[bool, typer.Option(help="Run on the embedded default site.")] = False,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/reconstruct"),
    seed: Annotated[int, typer.Option(help="The one seed of the run.")] = 0,
    n_samples: Annotated[int, typer.Option(help="Demo: landmarks to draw.")] = 5000,
    resolution: Annotated[float, typer.Option(help="Cell size of the map, m.")] = 4.0,
    crs: Annotated[str, typer.Option(help="CRS of the CSV coordinates.")] = "EPSG:32608",
) -> None:
    """Reconstruct a terrain map (mean and 1-sigma) with a Gaussian process.

    With --demo: the paper's Fig. 5 comparison (GP + satellite prior, constant-mean GP,
    Delaunay) on the default 600 m x 600 m site, printed as a table, with a PNG figure and a
    JSON summary in --out. With a CSV: a NetCDF map with elevation and elevation_std.
    """
    if demo == (samples is not None):
        raise bad_input(
            "SAMPLES / --demo",
            samples,
            "exactly one of a CSV path or --demo",
            "pass a CSV file, or --demo",
        )
    out_dir = ensure_writable_dir(out)
    if demo:
        from ..demo import reconstruction_demo
        from ..figures import plot_demo

        with console.status("reconstructing the default site..."):
            result = reconstruction_demo(seed=seed, n_samples=n_samples, resolution=resolution)
        _print_demo(result)
        png = plot_demo(result, out_dir / "demo.png")
        with atomic_path(out_dir / "demo_summary.json") as tmp:
            tmp.write_text(json.dumps(result.summary(), indent=2))
        console.print(f"wrote {png} and {out_dir / 'demo_summary.json'}")
        return

    from terrain.gp import TerrainGP

    data = _read_samples_csv(samples, crs)
    w, s = data.xy.min(axis=0)
    e, n = data.xy.max(axis=0)
    grid = Grid.from_bounds(
        (w, s, max(e, w + resolution), max(n, s + resolution)), resolution, crs=crs
    )
    with console.status(f"fitting a GP to {data.n} samples..."):
        ds = TerrainGP(seed=seed).fit(data).predict_grid(grid)
    target = out_dir / "reconstruction.nc"
    with atomic_path(target) as tmp:
        ds.to_netcdf(tmp, engine="scipy")
    console.print(f"wrote {target} ({grid.ny} x {grid.nx} cells, seed {seed})")
