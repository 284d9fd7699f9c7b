"""``glacimap run``: the main job, scenario → certified map and every product."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table


def run_command(
    config: Annotated[
        Path | None, typer.Option("--config", help="Scenario TOML (default: embedded).")
    ] = None,
    out: Annotated[Path, typer.Option("--out", help="Output folder.")] = Path("out/run"),
    seed: Annotated[int | None, typer.Option("--seed", help="Override the seed.")] = None,
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
    overrides = {"seed": seed} if seed is not None else None
    load_scenario(config, overrides)  # bad input fails here, before the progress display
    with Progress(
        TextColumn("{task.description:<12}"),
        BarColumn(),
        TextColumn("{task.completed:>5.0f}/{task.total:<5.0f}"),
        TimeElapsedColumn(),
        console=console,
        transient=False,
    ) as bar:
        tasks = {s: bar.add_task(s, total=1, start=False) for s in STAGES}

        def on_stage(name: str, state: str) -> None:
            if state == "start":
                bar.start_task(tasks[name])
            else:
                task = bar.tasks[tasks[name]]
                bar.update(tasks[name], completed=task.total)

        def on_progress(k: int, total: int) -> None:
            bar.update(tasks["localize"], total=total, completed=k)

        res = run_scenario(config, out, overrides, on_stage=on_stage, on_progress=on_progress)
    s, cert = res.summary, res.summary["certificate"]
    table = Table(title=f"glacimap run — seed {s['seed']} — {res.out}")
    table.add_column("quantity")
    table.add_column("value", justify="right")
    lo, hi = cert["accuracy"]["rmse_ci95_m"]
    table.add_row(
        "RMSE vs checkpoints (m)", f"{cert['accuracy']['rmse_m']:.3f} [{lo:.3f}, {hi:.3f}]"
    )
    for name, m in s["metrics"].items():
        table.add_row(f"RMSE vs truth, {name} (m)", f"{m['rmse']:.3f}")
    cov = s["metrics"]["gp_satellite"].get("coverage_95")
    if cov is not None:
        table.add_row("95 % interval coverage", f"{cov:.3f}")
    table.add_row("contour interval (m)", f"{cert['contour_interval']['certified_m']:g}")
    for v in cert.get("verdicts", []):
        table.add_row(f"{v['standard']} class", str(v.get("class")))
    for name, t in s["timings_s"].items():
        table.add_row(f"time: {name} (s)", f"{t:.1f}")
    console.print(table)
