"""``glacimap process``: a real survey's files -> certified products (no truth anywhere)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from ._breaklines import Breaklines, BreaklineTaper, BreaklineWidth, print_breakline_notes
from ._progress import certificate_rows, print_warnings, stage_progress


def process_command(
    log_dir: Annotated[
        Path,
        typer.Argument(help="The rover's field folder (survey.json) or a glacimap-log/1 folder."),
    ],
    prior: Annotated[
        Path | None,
        typer.Option("--prior", help="Satellite DEM (GeoTIFF or any GDAL raster, any CRS)."),
    ] = None,
    control: Annotated[
        Path | None, typer.Option("--control", help="Ground control CSV (any CRS).")
    ] = None,
    checkpoints: Annotated[
        Path | None,
        typer.Option("--checkpoints", help="Independent checkpoints CSV (any CRS)."),
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option("--config", help="Settings TOML (glacimap run --print-default keys)."),
    ] = None,
    bounds: Annotated[
        tuple[float, float, float, float] | None,
        typer.Option("--bounds", help="Map extent W S E N in the log's CRS (m)."),
    ] = None,
    out: Annotated[Path, typer.Option("--out", help="Output folder.")] = Path("out/process"),
    images: Annotated[
        bool,
        typer.Option(
            "--images/--no-images",
            help="When the folder has camera frames (images/: PNG + timestamps.csv), track "
            "them with the OpenCV front-end (docs/vision.md) instead of reading its tracks "
            "table.",
        ),
    ] = True,
    breaklines: Breaklines = None,
    breakline_width: BreaklineWidth = "auto",
    breakline_taper: BreaklineTaper = "auto",
    prior_as: Annotated[
        str | None,
        typer.Option(
            "--prior-as",
            help='How --prior is read: "mean" (a + b * DEM), "data" (its cells as samples '
            'with their own 1-sigma, measured on the survey) or "auto" (whichever maps the '
            "survey's held-out samples better). Default: [prior] as.",
        ),
    ] = None,
) -> None:
    """Ingest -> localize -> select -> reconstruct -> certify -> export -> report."""
    from toolkit.config import load_scenario
    from toolkit.prior_reading import prior_reading
    from toolkit.processing import PROCESS_STAGES, process

    console = Console()
    settings = load_scenario(config)  # bad settings fail before any work
    if prior_as is not None:  # --prior-as over the settings' [prior] as
        settings["prior"]["as"] = prior_as
    prior_reading(prior, settings, prior_as)  # "data" without --prior fails here too
    if breaklines is not None:  # a bad file fails before any work too
        from toolkit.breaklines_io import check_breakline_options

        check_breakline_options(breaklines, breakline_width, breakline_taper)
    if images:
        _say_frames(console, log_dir)
    with stage_progress(console, PROCESS_STAGES) as (on_stage, on_progress):
        res = process(
            log_dir,
            prior=prior,
            control=control,
            checkpoints=checkpoints,
            config=settings,
            out=out,
            bounds=bounds,
            on_stage=on_stage,
            on_progress=on_progress,
            images=images,
            on_frames=lambda k, n: on_progress(k, n, "ingest"),  # the front-end's frames
            breaklines=breaklines,
            breakline_width=breakline_width,
            breakline_taper=breakline_taper,
        )
    cert = res.summary["certificate"]
    table = Table(title=f"glacimap process — seed {res.summary['seed']} — {res.out}")
    table.add_column("quantity")
    table.add_column("value", justify="right")
    loc = cert.get("localization", {})
    table.add_row("keyframes", str(loc.get("keyframes")))
    table.add_row("GPS fixes used", str(loc.get("gps_used")))
    ing = cert.get("ingest") or {}
    if ing.get("clock_source"):  # a field folder: how its rover clock was tied to UTC
        se = (ing.get("clock_fit") or {}).get("standard_error_s")
        table.add_row(
            f"clock offset (s, {ing['clock_source']})",
            f"{ing['clock_offset_s']:.3f}" + (f" +- {se:.3f}" if se is not None else ""),
        )
    for reason, n in (loc.get("gps_skipped") or {}).items():
        table.add_row(f"  GPS skipped: {reason}", str(n))
    fe = ing.get("front_end")
    if fe:  # the feature tracks came from the camera front-end on the folder's frames
        how = "reused" if str(fe["source"]).startswith("reused") else "tracked"
        table.add_row(f"feature tracks (front-end, {how})", str(fe["tracks"]))
        for reason, n in (fe.get("frames_skipped") or {}).items():
            table.add_row(f"  frames skipped: {reason}", str(n))
    table.add_row("landmarks selected", str(loc.get("landmarks_selected")))
    if loc.get("control"):
        table.add_row("ground control used", str(len(loc["control"].get("used", []))))
    certificate_rows(table, cert)
    for name, t in res.summary["timings_s"].items():
        table.add_row(f"time: {name} (s)", f"{t:.1f}")
    console.print(table)
    # what the search found (--breaklines auto), then each step's height and where it dies out
    print_breakline_notes(console, cert, res.objects["reconstruction"].gp.mean_)
    if res.removed:
        console.print(
            f"removed {len(res.removed)} product(s) of an earlier run into {res.out} that this "
            f"run did not make: {', '.join(res.removed)}"
        )
    print_warnings(console, cert)


#: Front-end seconds per 640 x 480 frame on the 2 reference cores (docs/vision.md: 1,386
#: frames tracked in 228 s on a quiet machine, 506 s under load)
TRACK_SECONDS_PER_FRAME = (0.16, 0.37)


def _say_frames(console: Console, log_dir: Path) -> None:
    """Before the ingest: how many frames the front-end will track, and about how long."""
    import json

    folder = "images"
    try:  # a field folder's survey.json may name another frames folder
        folder = str(json.loads((log_dir / "survey.json").read_text()).get("images", folder))
    except (OSError, ValueError, AttributeError):
        pass  # no manifest, or one the reader will refuse with its own message
    stamps = log_dir / folder / "timestamps.csv"
    if not stamps.is_file():
        return
    n = max(sum(1 for _ in stamps.open()) - 1, 0)
    lo, hi = (n * s for s in TRACK_SECONDS_PER_FRAME)
    span = f"{lo:.0f}-{hi:.0f} s" if hi < 120 else f"{lo / 60:.0f}-{hi / 60:.0f} min"
    console.print(
        f"camera frames in {stamps.parent}: {n} to track with the OpenCV front-end, about "
        f"{span} (seconds if the tracks stored beside them match); --no-images reads the "
        "tracks table instead"
    )
