"""``glacimap plan``: a survey plan over a region, with its coverage metrics."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from terrain.errors import bad_input

console = Console()


def _read_prior(path: Path | None):
    """The prior DEM: a NetCDF with an ``elevation`` variable, or the embedded default site."""
    import xarray as xr

    from terrain import default_site

    if path is None:
        return default_site(resolution=4.0)
    if not path.is_file():
        raise bad_input("--prior", str(path), "an existing NetCDF DEM", "check the path")
    ds = xr.open_dataset(path, engine="scipy")
    if "elevation" not in ds:
        raise bad_input("--prior", list(ds.data_vars), "a variable named 'elevation'", "")
    return ds["elevation"].assign_attrs(ds.attrs).load()


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
        typer.Option(help="Prior DEM (NetCDF, variable 'elevation'); default: the embedded site."),
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
