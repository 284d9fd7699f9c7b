"""Shared pieces of the pipeline commands (``run``, ``process``): a progress bar per stage and
the certificate's summary rows."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table


def count_bar(console: Console, transient: bool = False) -> Progress:
    """One counting bar: description, bar, ``k/n``, elapsed time (frames, keyframes, tasks)."""
    return Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=transient,
    )


@contextmanager
def stage_progress(
    console: Console, stages: tuple[str, ...]
) -> Iterator[tuple[Callable[[str, str], None], Callable[[int, int], None]]]:
    """Yield ``(on_stage, on_progress)`` callbacks driving one bar per stage
    (``on_progress(k, K, stage="localize")``: ``k`` of ``K`` done in ``stage``)."""
    with Progress(
        TextColumn("{task.description:<12}"),
        BarColumn(),
        TextColumn("{task.completed:>5.0f}/{task.total:<5.0f}"),
        TimeElapsedColumn(),
        console=console,
        transient=False,
    ) as bar:
        tasks = {s: bar.add_task(s, total=1, start=False) for s in stages}

        def on_stage(name: str, state: str) -> None:
            if name not in tasks:
                return
            if state == "start":
                bar.start_task(tasks[name])
            else:
                bar.update(tasks[name], completed=bar.tasks[tasks[name]].total)

        def on_progress(k: int, total: int, stage: str = "localize") -> None:
            bar.update(tasks[stage], total=total, completed=k)

        yield on_stage, on_progress


def certificate_rows(table: Table, cert: dict[str, Any]) -> None:
    """Accuracy, held-out check, contour interval and verdicts of a certificate as rows."""
    acc = cert.get("accuracy")
    if acc:
        lo, hi = acc["rmse_ci95_m"]
        table.add_row("RMSE vs checkpoints (m)", f"{acc['rmse_m']:.3f} [{lo:.3f}, {hi:.3f}]")
        table.add_row("bias, map - checkpoint (m)", f"{acc['bias_m']:+.3f}")
        cps = cert.get("checkpoints") or {}
        if "n_used" in cps:
            table.add_row("checkpoints scored", f"{cps['n_used']} of {cps['n_total']}")
    held = cert.get("heldout_calibration")
    if held:
        pooled = held.get("pooled", held)
        for level in ("68", "95"):
            # the map's own 1-sigma checked on held-out samples with their noise removed (what
            # the README and report quote); the raw coverage of noisy samples only without it
            cov, ci = (
                pooled.get(f"map_coverage_{level}"),
                pooled.get(f"map_coverage_{level}_interval"),
            )
            if cov is not None:
                band = f" [{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]" if ci else ""
                table.add_row(
                    f"held-out {level} % coverage of the map (%)", f"{100 * cov:.1f}{band}"
                )
            elif f"coverage_{level}" in pooled:
                table.add_row(f"held-out coverage {level}", f"{pooled[f'coverage_{level}']:.3f}")
    ci = cert.get("contour_interval", {})
    if ci.get("certified_m"):
        table.add_row("contour interval (m)", f"{ci['certified_m']:g}")
    elif ci.get("uncertified_m"):
        table.add_row("contour interval (m, uncertified)", f"{ci['uncertified_m']:g}")
    for v in cert.get("verdicts", []):
        cls = str(v.get("class"))
        if v.get("passed") is False and v.get("notes"):  # a class named but not met
            cls += f" (not met: {v['notes'][0]})"
        table.add_row(f"{v['standard']} class", cls)


def print_warnings(console: Console, cert: dict[str, Any]) -> None:
    """The certificate's warnings (e.g. a dominant bias), one line each."""
    from rich.markup import escape  # messages name TOML tables, e.g. [prior]

    for w in cert.get("warnings", []):
        console.print(f"[yellow]warning:[/] {escape(str(w))}")
    held = cert.get("heldout_calibration") or {}
    for v in held.get("verdict") or []:  # the 1-sigma check in words (off by > 5 points)
        console.print(f"[yellow]held-out check:[/] {escape(str(v))}")
