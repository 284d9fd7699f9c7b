"""Progress where no terminal is attached (a log file, nohup, CI): plain timestamped lines.

rich draws a live bar only on a terminal; redirected, ``glacimap run --camera images`` printed
nothing for its whole 6-60 min (found running it under a log file). Reference values are hand
counts of the rule in :class:`toolkit.cli._progress.LineProgress`.
"""

from __future__ import annotations

import io
import re

from rich.console import Console

from toolkit.cli._progress import LineProgress, count_bar, stage_progress


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _lines(buf: io.StringIO) -> list[str]:
    return [re.sub(r"^\d\d:\d\d:\d\d ", "", ln) for ln in buf.getvalue().splitlines()]


def test_not_a_terminal_gets_lines_not_a_bar() -> None:
    buf = io.StringIO()
    console = Console(file=buf)
    assert not console.is_terminal
    assert isinstance(count_bar(console), LineProgress)
    with stage_progress(console, ("simulate", "localize")) as (on_stage, on_progress):
        on_stage("simulate", "start")
        on_progress(5, 10, "simulate")
        on_progress(10, 10, "simulate")  # all keyframes in; the stage still has work
        on_stage("simulate", "end")
        on_stage("localize", "start")
        on_stage("localize", "end")
    out = buf.getvalue()
    assert re.match(r"\d\d:\d\d:\d\d simulate: started", out)
    assert _lines(buf) == [
        "simulate: started",
        "simulate: done (0 s)",  # once, at the stage's end; 5/10 came < 10 s after "started"
        "localize: started",
        "localize: done (0 s)",
    ]


def test_tenths_at_least_min_gap_apart_and_every_s_without_a_total() -> None:
    buf, clock = io.StringIO(), _Clock()
    bar = LineProgress(Console(file=buf), every_s=60.0, min_gap_s=10.0, clock=clock)
    with bar:
        t = bar.add_task("frames", total=100)
        for k in range(1, 100):
            clock.t = 2.0 * k  # 2 s a frame: a tenth every 20 s
            bar.update(t, completed=k)
        clock.t = 200.0
        bar.update(t, completed=100)
        bar.update(t, completed=100)  # a second completion prints nothing
        u = bar.add_task("sweep tasks", total=None)
        clock.t = 230.0
        bar.update(u, completed=3)  # 30 s after its start line: nothing yet
        clock.t = 261.0
        bar.update(u, completed=4)  # 61 s: a line without a total
    assert _lines(buf) == [
        "frames: started",
        *[f"frames: {10 * j}/100 ({20 * j} s)" for j in range(1, 10)],
        "frames: done (200 s)",
        "sweep tasks: started",
        "sweep tasks: 4 (61 s)",
    ]


def test_descriptions_are_not_read_as_markup() -> None:
    buf = io.StringIO()
    bar = LineProgress(Console(file=buf))
    bar.add_task("rendering and tracking [sunny_snow]", total=1)
    assert "[sunny_snow]" in buf.getvalue()


def test_a_standard_without_a_class_says_why() -> None:
    """`paper class None` told a user nothing; the verdict's note says why (found on a
    1 m contour interval, which is not in the paper's Tables I-III)."""
    from rich.table import Table

    from toolkit.cli._progress import certificate_rows

    table = Table()
    table.add_column("q")
    table.add_column("v")
    cert = {
        "verdicts": [
            {"standard": "paper", "class": None, "passed": None, "notes": ["1 m is [off]"]},
            {"standard": "asprs2014", "class": None, "passed": False, "notes": ["NVA 6 m"]},
            {"standard": "nmas", "class": "NMAS", "passed": True, "notes": []},
        ]
    }
    certificate_rows(table, cert)
    buf = io.StringIO()
    Console(file=buf, width=200).print(table)
    out = buf.getvalue()
    assert "- (1 m is [off])" in out
    assert "None (not met: NVA 6 m)" in out
    assert "NMAS" in out
