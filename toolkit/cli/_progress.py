"""Shared pieces of the pipeline commands (``run``, ``process``): a progress bar per stage and
the certificate's summary rows.

On a terminal the bars are rich's. Anywhere else (a log file, ``nohup``, a batch job, CI) rich
draws a live display only when it stops, so an hour-long image run printed nothing until its
end; there :class:`LineProgress` prints plain, timestamped lines instead.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from ._interrupt import raise_if_interrupted


@dataclass
class _LineTask:
    description: str
    total: float | None
    completed: float = 0.0
    started: float | None = None  # the clock at its start (s)
    last_line: float = 0.0  # when its last line was printed
    last_step: int = 0  # the last tenth of the total printed
    done: bool = False


@dataclass
class LineProgress:
    """Progress as plain lines, for a console that is not a terminal.

    The subset of :class:`rich.progress.Progress` the commands use (``add_task``,
    ``start_task``, ``update``, a context manager). A task prints a line when it starts,
    when its count passes each tenth of its total or ``every_s`` seconds after its last line,
    and once when it completes, with the elapsed time::

        06:21:04 simulate: started
        06:21:40 simulate: 139/1386 (36 s)
        06:27:02 simulate: done (358 s)
    """

    console: Console
    every_s: float = 60.0
    min_gap_s: float = 10.0
    done_at_total: bool = True  # False: "done" only from finish() (a stage's end)
    clock: Callable[[], float] = time.monotonic  # seconds; a test passes its own
    tasks: list[_LineTask] = field(default_factory=list)

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def _say(self, task: _LineTask, text: str) -> None:
        stamp = time.strftime("%H:%M:%S")
        self.console.print(f"{stamp} {task.description}: {text}", markup=False, highlight=False)
        task.last_line = self.clock()

    def add_task(self, description: str, total: float | None = None, start: bool = True) -> int:
        self.tasks.append(_LineTask(str(description).strip(), total))
        if start:
            self.start_task(len(self.tasks) - 1)
        return len(self.tasks) - 1

    def finish(self, task_id: int) -> None:
        """Its "done" line, with the time since it started (once)."""
        task = self.tasks[task_id]
        self.start_task(task_id)
        if not task.done:
            task.done = True
            self._say(task, f"done ({self.clock() - (task.started or 0.0):.0f} s)")

    def start_task(self, task_id: int) -> None:
        task = self.tasks[task_id]
        if task.started is None:
            task.started = self.clock()
            self._say(task, "started")

    def update(
        self, task_id: int, total: float | None = None, completed: float | None = None
    ) -> None:
        task = self.tasks[task_id]
        self.start_task(task_id)
        if total is not None:
            task.total = total
        if completed is not None:
            task.completed = completed
        if task.done:
            return
        elapsed = self.clock() - (task.started or 0.0)
        if self.done_at_total and task.total and task.completed >= task.total:
            self.finish(task_id)
            return
        if not task.completed:
            return
        step = int(10 * task.completed / task.total) if task.total else task.last_step
        since = self.clock() - task.last_line
        if (step > task.last_step and since >= self.min_gap_s) or since >= self.every_s:
            task.last_step = max(step, task.last_step)
            of = f"/{task.total:.0f}" if task.total else ""
            self._say(task, f"{task.completed:.0f}{of} ({elapsed:.0f} s)")


def count_bar(console: Console, transient: bool = False) -> Progress | LineProgress:
    """One counting bar: description, bar, ``k/n``, elapsed time (frames, keyframes, tasks);
    plain lines (:class:`LineProgress`) when ``console`` is not a terminal."""
    if not console.is_terminal:
        return LineProgress(console)
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
    bar: Progress | LineProgress = (
        Progress(
            TextColumn("{task.description:<12}"),
            BarColumn(),
            TextColumn("{task.completed:>5.0f}/{task.total:<5.0f}"),
            TimeElapsedColumn(),
            console=console,
            transient=False,
        )
        if console.is_terminal
        else LineProgress(console, done_at_total=False)  # a stage is done when it ends
    )
    with bar:
        tasks = {s: bar.add_task(s, total=1, start=False) for s in stages}

        def on_stage(name: str, state: str) -> None:
            raise_if_interrupted()  # a Ctrl-C a library swallowed stops the run here
            if name not in tasks:
                return
            if state == "start":
                bar.start_task(tasks[name])
            elif isinstance(bar, LineProgress):
                bar.finish(tasks[name])
            else:
                bar.update(tasks[name], completed=bar.tasks[tasks[name]].total)

        def on_progress(k: int, total: int, stage: str = "localize") -> None:
            raise_if_interrupted()
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
                # held-out samples weighted to the map cells' whole neighbourhoods, when
                # that moved the check beyond chance (terrain.heldout_weights)
                ways = [
                    "neighbourhoods" if pooled.get("matched_on") == "neighbourhood" else "",
                    # held-out elevations from planes through their neighbours
                    # (terrain.heldout_local_fit)
                    "local planes" if pooled.get("local_fit_used") else "",
                ]
                how = f" ({', '.join(w for w in ways if w)})" if any(ways) else ""
                table.add_row(
                    f"held-out {level} % coverage of the map{how} (%)", f"{100 * cov:.1f}{band}"
                )
            elif f"coverage_{level}" in pooled:
                table.add_row(f"held-out coverage {level}", f"{pooled[f'coverage_{level}']:.3f}")
    as_data = (cert.get("reconstruction") or {}).get("prior_as_data")
    if as_data:  # the DEM's cells were samples: how many, their offset and 1-sigma
        table.add_row("prior DEM", as_data.removeprefix("prior DEM as data: "))
    chosen = (cert.get("reconstruction") or {}).get("prior_reading")
    if chosen:  # --prior-as auto: which reading, by which held-out RMSEs
        scores = chosen["scores"]
        table.add_row(
            "prior DEM read as (auto)",
            f"{chosen['choice']}: held-out RMSE {scores['mean']['heldout_rmse_m']:.3f} m as "
            f"mean, {scores['data']['heldout_rmse_m']:.3f} m as data",
        )
    ci = cert.get("contour_interval", {})
    if ci.get("certified_m"):
        table.add_row("contour interval (m)", f"{ci['certified_m']:g}")
    elif ci.get("uncertified_m"):
        table.add_row("contour interval (m, uncertified)", f"{ci['uncertified_m']:g}")
    for v in cert.get("verdicts", []):
        cls = str(v.get("class"))
        if v.get("passed") is False and v.get("notes"):  # a class named but not met
            cls += f" (not met: {v['notes'][0]})"
        elif v.get("passed") is None and v.get("class") is None and v.get("notes"):
            cls = f"- ({v['notes'][0]})"  # no class to judge (NSSDA reports; a CI off-table)
        table.add_row(f"{v['standard']} class", escape(cls))  # notes may hold [brackets]


def print_warnings(console: Console, cert: dict[str, Any]) -> None:
    """The certificate's warnings (e.g. a dominant bias), one line each."""
    # escape: messages name TOML tables, e.g. [prior]
    for w in cert.get("warnings", []):
        console.print(f"[yellow]warning:[/] {escape(str(w))}")
    held = cert.get("heldout_calibration") or {}
    for v in held.get("verdict") or []:  # the 1-sigma check in words (off by > 5 points)
        console.print(f"[yellow]held-out check:[/] {escape(str(v))}")
