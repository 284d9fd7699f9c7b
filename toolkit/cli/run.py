"""``glacimap run``: the main job, scenario → certified map and every product."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from ._breaklines import print_breakline_notes
from ._progress import certificate_rows, print_warnings, stage_progress


def run_command(
    config: Annotated[
        Path | None, typer.Option("--config", help="Scenario TOML (default: embedded).")
    ] = None,
    out: Annotated[Path, typer.Option("--out", help="Output folder.")] = Path("out/run"),
    seed: Annotated[int | None, typer.Option("--seed", help="Override the seed.")] = None,
    epoch: Annotated[
        int | None,
        typer.Option(
            "--epoch",
            help="Override the scenario's change.epoch: 2 = the site after its known change, "
            "surveyed anew (docs/change.md).",
        ),
    ] = None,
    camera: Annotated[
        str | None,
        typer.Option(
            "--camera",
            help="Override [field] camera: tracks (ideal feature tracks) or images (render the "
            "frames into OUT/field/rover/images; process tracks them with the OpenCV "
            "front-end; ~0.2-0.45 s a frame: the default survey 6-12 min).",
        ),
    ] = None,
    scene: Annotated[
        str | None,
        typer.Option("--scene", help="Override [field] scene (with images): sunny_snow, ..."),
    ] = None,
    print_default: Annotated[
        bool, typer.Option("--print-default", help="Print the embedded scenario and exit.")
    ] = False,
) -> None:
    """Plan → simulate → iSAM2 → select → reconstruct → certify → export → report."""
    from toolkit.config import load_scenario
    from toolkit.config import print_default as print_toml
    from toolkit.pipeline import STAGES, run_scenario

    console = Console()
    if print_default:
        print_toml()  # raw: rich wraps comments at 80 columns when stdout is not a terminal
        raise typer.Exit(0)
    overrides = {"seed": seed} if seed is not None else {}
    if epoch is not None:
        overrides["change"] = {"epoch": epoch}
    field = {k: v for k, v in (("camera", camera), ("scene", scene)) if v is not None}
    if field:
        overrides["field"] = field
    overrides = overrides or None
    load_scenario(config, overrides)  # bad input fails here, before the progress display
    with stage_progress(console, STAGES) as (on_stage, on_progress):
        res = run_scenario(
            config,
            out,
            overrides,
            on_stage=on_stage,
            on_progress=on_progress,
            on_frames=_frames_hook(console, on_progress),
        )
    s, cert = res.summary, res.summary["certificate"]
    table = Table(title=f"glacimap run — seed {s['seed']} — {res.out}")
    table.add_column("quantity")
    table.add_column("value", justify="right")
    certificate_rows(table, cert)
    for name, m in s["metrics"].items():
        table.add_row(f"RMSE vs truth, {name} (m)", f"{m['rmse']:.3f}")
        if "coverage_95" in m:
            table.add_row(f"  95 % coverage of the truth, {name}", f"{m['coverage_95']:.3f}")
    for name, t in s["timings_s"].items():
        table.add_row(f"time: {name} (s)", f"{t:.1f}")
    console.print(table)
    # [reconstruct] breaklines: what the search found ("auto"), then each fitted step
    print_breakline_notes(console, cert, res.objects["reconstruction"].gp.mean_)
    print_warnings(console, cert)


def _frames_hook(console: Console, on_progress):
    """``on_frames(k, K)`` for ``[field] camera = "images"``: the frame count and time estimate
    on the first rendered frame (the plan is made inside the run), then the simulate bar."""
    from .simulate import say_image_frames

    said = False

    def on_frames(k: int, n: int) -> None:
        nonlocal said
        if not said:
            said = True
            say_image_frames(console, n)
        on_progress(k, n, "simulate")

    return on_frames
