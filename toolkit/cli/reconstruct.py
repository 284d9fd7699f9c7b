"""``glacimap reconstruct``: a terrain map with 1-sigma from elevation samples, or the demo."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from terrain.atomic import atomic_path
from terrain.errors import bad_input

from ._breaklines import Breaklines, BreaklineTaper, BreaklineWidth

console = Console()
#: What ``reconstruct SAMPLES.csv`` wrote (the next run into --out replaces it all).
SUMMARY = "reconstruct_summary.json"


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
        list[Path] | None,
        typer.Argument(
            help="CSV: x, y, z[, z_var, track_z_std_m, shared_offset_std_m] (aliases "
            "allowed); or a GNSS log of the survey (NMEA, GPX, RTKLIB .pos); several files "
            "are one survey (its days)."
        ),
    ] = None,
    demo: Annotated[bool, typer.Option(help="Run on the embedded default site.")] = False,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/reconstruct"),
    seed: Annotated[int, typer.Option(help="The one seed of the run.")] = 0,
    n_samples: Annotated[int, typer.Option(help="Demo: landmarks to draw.")] = 5000,
    resolution: Annotated[float, typer.Option(help="Cell size of the map, m.")] = 4.0,
    crs: Annotated[
        str | None,
        typer.Option(help="CRS of the CSV coordinates, when no crs column or sidecar names it."),
    ] = None,
    prior: Annotated[
        Path | None,
        typer.Option("--prior", help="Satellite DEM as the GP prior mean (any CRS)."),
    ] = None,
    bounds: Annotated[
        tuple[float, float, float, float] | None,
        typer.Option("--bounds", help="Map extent W S E N (m, the samples' CRS)."),
    ] = None,
    like: Annotated[
        Path | None,
        typer.Option(
            "--like",
            help="Take the map grid from this raster (projected CRS; the samples are "
            "projected into it when it differs).",
        ),
    ] = None,
    checkpoints: Annotated[
        Path | None, typer.Option("--checkpoints", help="Independent checkpoints: certify.")
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option(
            "--config",
            help="Settings TOML: its reconstruct, prior and certify tables "
            "(keys of glacimap run --print-default).",
        ),
    ] = None,
    anisotropy: Annotated[
        str | None,
        typer.Option(
            "--anisotropy",
            help='Ground smoother along one azimuth: "none" (default), "auto" (chosen by '
            'evidence) or "AZIMUTH,RATIO" (degrees from grid north; e.g. a glacier\'s flow).',
        ),
    ] = None,
    breaklines: Breaklines = None,
    breakline_width: BreaklineWidth = "auto",
    breakline_taper: BreaklineTaper = "auto",
    horizontal_sd: Annotated[
        float | None,
        typer.Option(
            "--horizontal-sd",
            help="The samples' own horizontal 1-sigma, m (digitised contours: the source "
            "map's positional accuracy, ~10-15 m at 1:50,000): its error through the map's "
            "slope joins the 1-sigma and the held-out check. Default: none.",
        ),
    ] = None,
    antenna_height: Annotated[
        float | None,
        typer.Option(
            "--antenna-height",
            help="GNSS log as SAMPLES: the antenna's height above the surface, m "
            "(subtracted from every fix).",
        ),
    ] = None,
    gnss_heights: Annotated[
        str | None,
        typer.Option(
            "--gnss-heights",
            help="GNSS log as SAMPLES: what its heights are above where the file does not "
            'say (GPX ele, NMEA without the geoid separation): "ellipsoidal", "egm96", '
            '"egm2008", or "auto" (GPX above EGM96, NMEA ellipsoidal; said). Carried to '
            "the WGS 84 ellipsoid, the map's datum.",
        ),
    ] = None,
    samples_heights: Annotated[
        str | None,
        typer.Option(
            "--samples-heights",
            help="What a CSV's z are above: ellipsoidal, egm96, egm2008, or a national "
            "vertical CRS (EPSG:5941 NN2000, EPSG:5703 NAVD88...). The map is in the "
            "samples' datum and says so; without, it says the datum is not stated.",
        ),
    ] = None,
    block_size: Annotated[
        str,
        typer.Option(
            "--block-size",
            help="Dense points (lidar, drone clouds) as block means: auto (a survey of over "
            "100,000 samples reduced to at most 50,000), none, or a block edge in metres.",
        ),
    ] = "auto",
    point_classes: Annotated[
        str | None,
        typer.Option(
            "--point-classes",
            help="LAS / LAZ as SAMPLES: the ASPRS classes to map, e.g. 2,9 (default: ground, "
            "class 2, when classified; else all but noise).",
        ),
    ] = None,
    prior_as: Annotated[
        str | None,
        typer.Option(
            "--prior-as",
            help='How --prior is read: "mean" (a + b * DEM, the default), "data" (its '
            "cells as samples with their own 1-sigma, measured on the survey: for a DEM "
            'noisier than the survey\'s interpolation) or "auto" (whichever maps the '
            "survey's held-out samples better). Default: --config's [prior] as.",
        ),
    ] = None,
) -> None:
    """Reconstruct a terrain map (mean and 1-sigma) with a Gaussian process.

    With --demo: the paper's Fig. 5 comparison (GP + satellite prior, constant-mean GP,
    Delaunay) on the default 600 m x 600 m site. With a CSV: the same model and products as
    glacimap run / process (kernel by evidence, the prior DEM's offset fitted, total and
    relative 1-sigma, COG, contours, mesh; a certificate and report with --checkpoints).
    A GNSS log (a kinematic profile) is read as its fixes, projected to --crs or their UTM
    zone; a GIS layer (GeoPackage, Shapefile, GeoJSON: points or contour lines) as its
    vertices; a LAS / LAZ cloud as its ground points, in block means when dense
    (--block-size). The samples they gave are written as samples.csv beside the map.
    """
    samples = samples or None  # typer gives [] for none
    if demo == (samples is not None):
        raise bad_input(
            "SAMPLES / --demo",
            None if samples is None else [str(p) for p in samples],
            "exactly one of: sample files (CSV, GNSS logs, GIS layers, LAS / LAZ), or --demo",
            "pass the survey's files, or --demo",
        )
    if bounds is not None and like is not None:
        raise bad_input("--bounds / --like", "both", "at most one", "pass one of them")
    if gnss_heights is not None:  # checked before anything is read, too
        from terrain.vertical_datum import height_datum_option

        gnss_heights = height_datum_option(gnss_heights, "--gnss-heights", allow_auto=True)
    if prior_as is not None:  # before anything is read: a bad value fails in milliseconds
        from ..prior_reading import prior_reading

        prior_reading(prior, {}, prior_as)
    if horizontal_sd is not None:  # before the fit: a bad value fails in milliseconds
        from terrain.errors import positive_number

        fix = "the samples' horizontal 1-sigma in metres, e.g. --horizontal-sd 12"
        horizontal_sd = positive_number("--horizontal-sd", horizontal_sd, fix, allow_zero=True)
    from ..point_files import point_classes_option
    from ..sample_blocks import block_size_option

    reading = {  # how the sample files are read, checked before anything is
        "antenna_height_m": antenna_height,
        "gnss_heights": gnss_heights,
        "point_classes": point_classes_option(point_classes),
        "block_size": block_size_option(block_size),
    }
    from ..export._files import output_folder

    with output_folder(out) as out_dir:  # a failed run leaves no empty --out behind
        if demo:
            _run_demo(out_dir, seed, n_samples, resolution)
            return
        overrides = {"seed": seed}
        if anisotropy is not None:  # checked by the scenario's own rule (config.py)
            overrides["reconstruct"] = {"anisotropy": anisotropy}
        lines = None
        if breaklines is not None:  # checked before the fit: a bad file fails in milliseconds
            from ..breaklines_io import check_breakline_options

            shape = check_breakline_options(breaklines, breakline_width, breakline_taper)
            lines = (breaklines, *shape)
        _reconstruct_csv(
            samples,
            out_dir,
            overrides,
            resolution,
            crs,
            prior,
            bounds,
            like,
            checkpoints,
            config,
            lines,
            horizontal_sd,
            reading,
            prior_as,
            samples_heights,
        )


def _run_demo(out_dir: Path, seed: int, n_samples: int, resolution: float) -> None:
    from ..demo import reconstruction_demo
    from ..figures import plot_demo

    with console.status("reconstructing the default site..."):
        result = reconstruction_demo(seed=seed, n_samples=n_samples, resolution=resolution)
    _print_demo(result)
    png = plot_demo(result, out_dir / "demo.png")
    with atomic_path(out_dir / "demo_summary.json") as tmp:
        tmp.write_text(json.dumps(result.summary(), indent=2))
    console.print(f"wrote {png} and {out_dir / 'demo_summary.json'}")


def _file(lines: Any) -> Any:
    """The breaklines' file, or None for ``--breaklines auto`` (found, not read)."""
    from ..breaklines_io import is_search

    return None if is_search(lines) else lines


def _reconstruct_csv(
    samples, out_dir, overrides, resolution, crs, prior, bounds, like, cps, cfg, lines=None,
    horizontal_sd=None, reading=None, prior_as=None, samples_heights=None,
):  # fmt: skip
    import warnings

    from terrain.errors import DegenerateFitWarning, TilingWarning

    from ..config import load_scenario
    from ..export._files import previous_products, remove_stale, staged_folder
    from ..grid_like import grid_like
    from ..prior_reading import choose_reading, prior_reading, reading_record
    from ..processing import prior_mean
    from ..products import write_csv, write_map_products
    from ..provenance import input_record
    from ..samples_io import read_sample_files, sample_columns, samples_height_attrs
    from ..stages import certify_stage, map_grid, reconstruct_stage

    settings = load_scenario(cfg, overrides)
    if lines is None:  # --config's [reconstruct] breaklines (with their width and taper)
        from ..breaklines_io import scenario_lines

        given = scenario_lines(settings)
        lines = given if given[0] is not None else None
    seed = int(overrides["seed"])
    heights = samples_height_attrs(samples, samples_heights)  # before the read: fails fast
    table = read_sample_files(samples, crs, **(reading or {}))
    if table.note:
        console.print(f"[yellow]note:[/] {escape(str(table.note))}")
    if like is not None:  # the raster's own cells; samples projected into its CRS if need be
        grid, table, moved = grid_like(like, table)
        if moved:
            console.print(f"[yellow]note:[/] {escape(str(moved))}")
        data = table.samples
    else:
        data = table.samples
        grid = map_grid(bounds, resolution, data.crs, data)
    checkpoints = None
    if cps is not None:  # read and placed before the fit: a wrong CRS fails in seconds
        from ..certify import require_checkpoints_on

        checkpoints = require_checkpoints_on(cps, grid)
    footprint = _footprint_note(data, grid)
    if footprint:  # said before the fit: a big map of few samples is long to wait for
        console.print(f"[yellow]warning:[/] {escape(str(footprint))}")
    survey, as_data, choice = data, None, None
    reading = prior_reading(prior, settings, prior_as)
    mean = "constant" if reading == "data" else prior_mean(prior, settings)
    if reading == "auto":  # the reading the survey's held-out samples map better
        with console.status("choosing how the prior DEM is read (held-out samples)..."):
            choice = choose_reading(prior, mean, survey, grid, settings, seed)
        if isinstance(choice, str):  # too few samples to hold out: the default, said
            console.print(f"[yellow]warning:[/] {escape(choice)}")
            choice, reading = None, "mean"
        else:
            console.print(f"[yellow]note:[/] {escape(choice.note())}")
            reading = choice.choice
        mean = "constant" if reading == "data" else mean
    if reading == "data":  # its cells as samples (dem_as_data.py)
        from terrain.dem_as_data import dem_as_data

        data, as_data = dem_as_data(prior, survey, grid.bounds)
        console.print(f"[yellow]note:[/] {escape(as_data.note())}")
    if lines is not None:  # a step across each breakline, read now in the map's CRS
        from ..breaklines_io import with_breaklines

        notes: list[str] = []
        mean = with_breaklines(mean, *lines, crs=data.crs, notes=notes, samples=survey)
        for note in notes:  # e.g. reprojected from EPSG:4326; or what the search found
            console.print(f"breaklines: {escape(note)}")
        searched = "; ".join(notes) if _file(lines[0]) is None else None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DegenerateFitWarning)
        warnings.simplefilter("always", TilingWarning)
        with console.status(f"fitting a GP to {data.n} samples..."):
            rec = reconstruct_stage(
                data,
                grid,
                mean,
                settings,
                seed,
                landmark_xy=survey.xy,
                landmark_rel_z_std=table.track_z_std,
                landmark_t_s=survey.extra.get("t_s"),
                shared_z_std=table.shared_z_std,
                heldout_folds=int(settings["certify"]["heldout_folds"]),
                horizontal_sd=horizontal_sd,
                # the choice's own fit of that reading, unless steps joined its mean
                fitted=None if choice is None or lines is not None else choice.models[reading],
            )
    if lines is not None:  # each step's height, and where it dies out inside the survey
        from ..breaklines_io import step_notes

        for note in step_notes(rec.gp.mean_):
            console.print(f"breaklines: {escape(note)}")
    said = set()  # each once: the held-out check's folds refit and warn again
    for w in caught:
        if issubclass(w.category, DegenerateFitWarning) and str(w.message) not in said:
            said.add(str(w.message))
            console.print(f"[yellow]warning (degenerate fit):[/] {escape(str(w.message))}")
    if any(issubclass(w.category, TilingWarning) for w in caught) and rec.gp.tiling_note_:
        # the map's own (recorded in the product); the folds' tiles differ by design
        console.print(f"[yellow]warning (tiles):[/] {escape(rec.gp.tiling_note_)}")
    reverted = _reverted_fraction(rec)
    if reverted > 0.5 and prior is not None:  # by design: the DEM fills the gaps
        console.print(
            f"[yellow]note:[/] on {100 * reverted:.0f} % of the cells the samples add little "
            "(their 1-sigma is within 10 % of the prior's): the map there is the prior DEM "
            "with its fitted offset and scale, and its 1-sigma says so"
        )
    elif reverted > 0.5:  # a constant mean: a flat map where the samples do not reach
        console.print(
            f"[yellow]warning:[/] the map reverts to its prior mean on {100 * reverted:.0f} % of "
            "the cells (their 1-sigma is within 10 % of the prior's): the samples do not "
            "constrain most of this grid; narrow --bounds or add samples"
        )
    rec.product.attrs.update(heights)  # a CSV's datum, or that it is not stated
    from terrain.mass_balance import survey_date_attrs

    rec.product.attrs.update(survey_date_attrs(survey.extra.get("t_s")))  # a log's UTC dates
    if as_data is not None:
        rec.product.attrs["prior_as_data"] = as_data.note()
    if choice is not None:
        rec.product.attrs["prior_reading"] = reading_record(choice)
    if lines is not None and searched:  # what the search found and dropped, with the map
        rec.product.attrs["breakline_search"] = searched
    # which files made the map, by name and SHA-256 (every product's metadata)
    rec.product.attrs["inputs"] = json.dumps(
        [
            {k: r[k] for k in ("role", "name", "sha256")}
            for r in (
                *(input_record("samples", p) for p in samples),
                input_record("prior", prior),
                input_record("checkpoints", cps),
                input_record("breaklines", None if lines is None else _file(lines[0])),
            )
            if r is not None
        ]
    )
    cert = certify_stage(rec, checkpoints, settings, seed) if checkpoints is not None else None
    if cert is None and rec.heldout is not None:
        from ..breakline_record import breakline_block
        from ..certify import heldout_block

        cert = {"seed": seed, "heldout_calibration": heldout_block(rec.heldout)}
        cert.update(breakline_block(rec.product.attrs))  # the cliffs the map was fitted with
        if rec.product.attrs.get("prior_note"):  # certify_stage states it with checkpoints
            cert["warnings"] = [rec.product.attrs["prior_note"]]
    before = previous_products(out_dir, SUMMARY)
    with staged_folder(out_dir) as tmp:
        write_map_products(tmp, rec, cert, settings)
        if table.derived:  # the samples a log, layer or cloud gave: change reads them
            write_csv(tmp / "samples.csv", sample_columns(table))
        written = sorted([p.name for p in tmp.iterdir()] + [SUMMARY])
        summary = {"seed": seed, "samples": data.n, "grid": list(grid.shape), "products": written}
        with atomic_path(tmp / SUMMARY) as path:
            path.write_text(json.dumps(summary, indent=2))
    removed = remove_stale(out_dir, before, written)
    table_out = Table(title=f"glacimap reconstruct — seed {seed} — {out_dir}")
    table_out.add_column("quantity")
    table_out.add_column("value", justify="right")
    table_out.add_row("samples", str(data.n))
    table_out.add_row("grid", f"{grid.ny} x {grid.nx} cells of {grid.resolution[0]:g} m")
    table_out.add_row("kernel (by evidence)", str(rec.product.attrs.get("kernel")))
    if not rec.gp.anisotropy_.isotropic:  # a grain given or chosen (--anisotropy)
        table_out.add_row("ground's grain", rec.gp.anisotropy_.describe())
    noise = getattr(rec.gp, "noise_estimate_", None)
    if noise:  # no sample stated its noise: the windows measured it (terrain/unstated_noise)
        table_out.add_row(
            "noise, stated by none (from dense windows)", f"{noise['nugget'] ** 0.5:.3g} m"
        )
    table_out.add_row("mean", str(rec.product.attrs.get("mean_function")))
    table_out.add_row("cells reverting to the prior", f"{100 * reverted:.1f} %")
    if cert is not None:
        from ._progress import certificate_rows

        certificate_rows(table_out, cert)
    console.print(table_out)
    if cert is not None:  # the held-out verdict in words (sigma too small / too large)
        from ._progress import print_warnings

        print_warnings(console, cert)
    console.print("wrote " + ", ".join(written))
    if removed:  # a run with --checkpoints before: its report.html described another map
        console.print(f"removed {', '.join(removed)} of an earlier run into {out_dir}")


#: Below this share of the map inside the samples' bounding box, reconstruct warns up front.
MIN_SAMPLED_SHARE = 0.1


def _footprint_note(data, grid) -> str:
    """A warning when the samples' bounding box covers under :data:`MIN_SAMPLED_SHARE` of the
    map (``--bounds`` / ``--like`` far larger than the survey): a 10 km square at 4 m around
    a 600 m survey ran for minutes with no word (6.25 million cells, mostly prior)."""
    w, s, e, n = grid.bounds
    x0, y0 = np.maximum(data.xy.min(axis=0), (w, s))
    x1, y1 = np.minimum(data.xy.max(axis=0), (e, n))
    inside = max(x1 - x0, 0.0) * max(y1 - y0, 0.0)
    area = (e - w) * (n - s)
    share = inside / area if area > 0 else 1.0
    if share >= MIN_SAMPLED_SHARE:
        return ""
    return (
        f"the samples' bounding box covers {100 * share:.2g} % of the map ({inside / 1e6:.3g} "
        f"of {area / 1e6:.3g} km^2, {grid.ny * grid.nx:,} cells): the rest is the prior mean "
        "with the prior's 1-sigma, and the map, its mesh and contours take long to make; "
        "narrow --bounds (or --like) to the survey"
    )


def _reverted_fraction(rec) -> float:
    """Share of cells whose relative 1-sigma is within 10 % of the GP's prior 1-sigma."""
    rel = rec.product["elevation_std_relative"].values
    prior_sd = float(np.sqrt(rec.gp.kernel_.variance))
    return float(np.mean(rel > 0.9 * prior_sd))
