"""``glacimap certify``: accuracy certificate of a DEM against independent checkpoints."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

console = Console()


def _num(value: Any, unit: str = " m") -> str:
    return "—" if value is None else f"{value:.3f}{unit}"


def print_certificate(cert: dict[str, Any]) -> None:
    """Print the accuracy summary and the verdict table of a certificate (rich)."""
    acc, cps, ci = cert["accuracy"], cert["checkpoints"], cert["contour_interval"]
    lo, hi = acc["rmse_ci95_m"]
    dropped = ", ".join(f"{d['count']} {k.replace('_', ' ')}" for k, d in cps["dropped"].items())
    console.print(
        f"RMSE_z {acc['rmse_m']:.3f} m [95 % CI {lo:.3f}, {hi:.3f}] from {cps['n_used']} of "
        f"{cps['n_total']} checkpoints (dropped: {dropped}); bias {acc['bias_m']:+.3f} m, "
        f"(map - checkpoint), NSSDA Accuracy_z {acc['accuracy_95_m']:.3f} m; contour interval "
        f"{ci['certified_m']:g} m ({ci['how']}); seed {cert['seed']}"
    )
    for warning in cert.get("warnings") or []:
        console.print(f"[bold yellow]warning:[/] {escape(warning)}", highlight=False)
    moved = cert["checkpoints"].get("reprojected")
    if moved:
        from pyproj import CRS

        names = [CRS.from_user_input(moved[k]).name for k in ("from", "to")]  # not a WKT page
        console.print(f"checkpoints reprojected from {names[0]} to {names[1]} (pyproj)")
    cal = cert.get("calibration")
    if cal:
        console.print(
            f"1-sigma at the checkpoints: {100 * cal['coverage_68']:.1f} % inside ±1σ, "
            f"{100 * cal['coverage_95']:.1f} % inside ±1.96σ (nominal 68.3 / 95 %)"
        )
    table = Table(title=f"Verdicts at a {ci['certified_m']:g} m contour interval")
    for col in ("standard", "class", "passed", "RMSE m", "limit m", "notes"):
        table.add_column(col, justify="right" if col.endswith(" m") else "left")
    marks = {True: "[green]pass[/]", False: "[red]fail[/]", None: "—"}
    for v in cert["verdicts"]:
        table.add_row(
            v["standard"],
            v["class"] or "—",
            marks[v["passed"]],
            _num(v["rmse_m"], ""),
            _num(v["limit_m"], ""),
            "; ".join(v["notes"]),
        )
    console.print(table)


def certify_command(
    dem: Annotated[
        Path, typer.Argument(help="DEM: GeoTIFF (band 1 elevation) or NetCDF terrain product.")
    ],
    checkpoints: Annotated[
        Path,
        typer.Argument(
            help="CSV or Parquet with x, y, z[, z_std, crs] (or easting, northing, elevation, "
            "lon, lat, h, sigma_z ...), any CRS: reprojected to the DEM's."
        ),
    ],
    out: Annotated[Path | None, typer.Option(help="Write the certificate JSON here.")] = None,
    contour_interval: Annotated[
        float | None,
        typer.Option(help="Contour interval to certify, m (default: finest ASPRS 1990 Class 1)."),
    ] = None,
    checkpoint_rmse: Annotated[
        float | None,
        typer.Option(
            help="RMSE of the checkpoint survey itself, m (default: the RMS of the "
            "checkpoints' z_std column when they have one, else 0)."
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the bootstrap.")] = 0,
    n_boot: Annotated[int, typer.Option(help="Bootstrap resamples for the RMSE CI.")] = 2000,
    crs: Annotated[
        str | None, typer.Option(help="CRS of the checkpoints if the file names none.")
    ] = None,
    feature: Annotated[str, typer.Option(help="ASPRS 1990 feature: contour or spot.")] = "contour",
    dem_heights: Annotated[
        str | None,
        typer.Option(
            help="What the DEM's heights are above if it does not say (its compound CRS, a "
            "glacimap product): ellipsoidal, egm96 (SRTM, NASADEM, ASTER), egm2008 (GLO-30), "
            "or a national vertical CRS (EPSG:5941 NN2000, EPSG:5703 NAVD88...)."
        ),
    ] = None,
    checkpoint_heights: Annotated[
        str | None,
        typer.Option(
            help="The same for the checkpoints (stated by a compound or 3-D crs, e.g. "
            "EPSG:4979); carried to the DEM's datum when both are known."
        ),
    ] = None,
) -> None:
    """Certify a DEM's vertical accuracy against independent checkpoints: RMSE_z with a
    bootstrap 95 % CI, bias, NSSDA Accuracy_z, the contour interval it supports and a verdict
    per standard (paper, ASPRS 1990/2014/2023, NSSDA, NMAS); writes the JSON with --out."""
    from ..certify import certify, check_output_path, write_certificate

    if out is not None:
        check_output_path(out)  # fail before any work
    cert = certify(
        dem,
        checkpoints,
        contour_interval_m=contour_interval,
        checkpoint_rmse_m=checkpoint_rmse,
        seed=seed,
        n_boot=n_boot,
        feature=feature,
        crs=crs,
        dem_heights=dem_heights,
        checkpoint_heights=checkpoint_heights,
    )
    console.print(f"heights: {cert['checkpoints']['heights']['note']}")
    print_certificate(cert)
    if out is not None:
        console.print(f"wrote {write_certificate(cert, out)}")
