"""``glacimap localize``: iSAM2 over a measurement log, landmark selection, terrain samples."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from terrain.errors import InputError, bad_input

from ._progress import count_bar
from .simulate import FORMATS

console = Console()

#: Files written into --out ({fmt}: csv or parquet).
FILES = {
    "trajectory": "trajectory.{fmt}",  # one row per keyframe (pipeline.trajectory_table)
    "landmarks": "landmarks.{fmt}",  # one row per landmark in the graph (landmark_table)
    "samples": "samples.csv",  # selected landmarks x, y, z, z_var: glacimap reconstruct's input
    "summary": "localize_summary.json",  # counts, timings, settings
}
_LOG_TABLES = ("keyframes", "odometry", "gps", "observations", "landmarks")


def read_log_folder(log_dir: Path, images: bool = True):
    """:func:`factorgraph.log.read_log`, with a file that pandas / pyarrow cannot parse named
    in the message instead of a bare parser error; a rover's field folder (``survey.json``,
    docs/field-format.md) is read as ``glacimap process`` reads it (its ``images/`` tracked
    by the front-end unless ``images`` is False)."""
    import pandas as pd

    from factorgraph.log import read_log

    if not log_dir.is_dir():
        raise bad_input(
            "LOG_DIR", str(log_dir), "an existing log folder", "run glacimap simulate --out DIR"
        )
    if (log_dir / "survey.json").is_file():
        from factorgraph.field import read_field_log

        with _frames_bar() as progress:  # counts the frames when the front-end tracks them
            log, report = read_field_log(log_dir, images=images, progress=progress)
        for line in report.lines():
            console.print(line)
        return log
    try:
        return read_log(log_dir)
    except InputError:
        raise
    except (ValueError, KeyError, TypeError, OSError) as exc:
        for name in _LOG_TABLES:  # which file is it?
            for ext, reader in (("parquet", pd.read_parquet), ("csv", pd.read_csv)):
                path = log_dir / f"{name}.{ext}"
                if not path.exists():
                    continue
                try:
                    reader(path)
                except Exception as inner:  # pandas / pyarrow parser errors
                    raise bad_input(
                        path.name, str(inner)[:200], f"a readable {ext.upper()} table", "repair it"
                    ) from exc
                break
        raise bad_input(
            "LOG_DIR", str(log_dir), "a measurement log (factorgraph/log.py)", f"{exc!r}"
        ) from exc


def _write_table(cols: dict[str, Any], path: Path, fmt: str) -> None:
    import pandas as pd

    from terrain.atomic import atomic_path

    df = pd.DataFrame(cols)
    with atomic_path(path) as tmp:
        if fmt == "csv":
            df.to_csv(tmp, index=False, float_format="%.12g")
        else:
            df.to_parquet(tmp, index=False)


def _print_counts(summary: dict[str, Any], files: list[Path]) -> None:
    counts = summary["selection_counts"]
    never = counts["never_initialised"]
    table = Table(title=f"iSAM2 localization — {summary['keyframes']} keyframes")
    table.add_column("quantity")
    table.add_column("value", justify="right")
    rows = {
        "driving time (s)": f"{summary['duration_s']:.0f}",
        "tracks never triangulated": f"{sum(never.values())} "
        + ("(" + ", ".join(f"{k} {v}" for k, v in never.items()) + ")" if never else ""),
        "landmarks triangulated (in the graph)": f"{counts['in_graph']}",
        "dropped: 1-sigma above max": f"{counts['sigma_above_max']}",
        "dropped: first seen too close": f"{counts['first_seen_too_close']}",
        "landmarks selected": f"{counts['kept']}",
        "iSAM2 step median / p95 (ms)": f"{1e3 * summary['step_median_s']:.1f} / "
        f"{1e3 * summary['step_p95_s']:.1f}",
        "landmark marginals (s)": f"{summary['marginals_s']:.2f}",
        "iSAM2 rebuilds": f"{summary['isam2_rebuilds']}",
        "shared offset 1-sigma E, N, U (m)": ", ".join(
            f"{v:.2f}" for v in summary["shared_offset_std_m"]
        ),
    }
    gps_skipped = summary.get("gps_skipped") or {}
    if gps_skipped:
        reasons = ", ".join(f"{k} {v}" for k, v in sorted(gps_skipped.items()))
        rows["GPS fixes skipped"] = f"{sum(gps_skipped.values())} ({reasons})"
    rows["expected horizontal RMSE, from the marginals (m)"] = (
        f"{summary['predicted_horizontal_rmse_m']:.2f}"
    )
    if "frame_floor_m" in summary:
        rows["best possible: mean-bias floor / frame floor (m)"] = (
            f"{summary['horizontal_floor_m']:.2f} / {summary['frame_floor_m']:.2f}"
        )
    if "horizontal_rmse_m" in summary:
        rows["keyframe RMSE vs truth, horiz. / vert. (m)"] = (
            f"{summary['horizontal_rmse_m']:.2f} / {summary['vertical_rmse_m']:.2f}"
        )
    if "landmark_nees_mean" in summary:
        rows["landmark NEES (3 if consistent)"] = f"{summary['landmark_nees_mean']:.2f}"
    for k, v in rows.items():
        table.add_row(k, v)
    console.print(table)
    console.print("wrote " + ", ".join(str(f) for f in files))


def _print_front_end(record: dict) -> None:
    """One line on what the camera front-end did (``track_log_frames``' record)."""
    console.print(
        f"front-end on {record['folder']} ({record['source']}): {record['tracks']} tracks, "
        f"{record['views_per_keyframe']:.1f} views per keyframe; frames skipped: "
        f"{record['frames_skipped'] or 'none'}; rejected: "
        + ", ".join(f"{k} {v}" for k, v in record["rejected"].items())
        + (
            ""
            if record["same_as_log"]
            else "; tracks differ from the log's table: landmark truth not used"
        )
    )


def _frames_bar():
    """A context giving ``progress(k, K)`` that draws a bar of frames tracked (nothing is
    drawn when it is never called: stored tracks reused, or no frames)."""
    from contextlib import contextmanager

    @contextmanager
    def bar():
        with count_bar(console, transient=True) as p:
            task = None

            def progress(k: int, n: int) -> None:
                nonlocal task
                if task is None:
                    task = p.add_task("front-end: frames tracked", total=n)
                p.update(task, total=n, completed=k)

            yield progress

    return bar()


def _track_images(log, folder: Path):
    """``log`` with its observations from the front-end run on ``folder``'s frames, and
    what the front-end did for ``localize_summary.json`` (:func:`track_log_frames`)."""
    from factorgraph.vision import track_log_frames

    with _frames_bar() as progress:
        log, record = track_log_frames(log, folder, progress=progress)
    _print_front_end(record)
    return log, record


def localize_command(
    log_dir: Annotated[
        Path,
        typer.Argument(
            help="Log folder (glacimap simulate) or a rover's field folder (survey.json)."
        ),
    ],
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/localize"),
    config: Annotated[
        Path | None,
        typer.Option("--config", help="Scenario TOML: its localize and select tables."),
    ] = None,
    max_sigma: Annotated[
        float | None, typer.Option(help="Select: largest landmark 1-sigma, m (paper: 0.5).")
    ] = None,
    min_first_seen: Annotated[
        float | None, typer.Option(help="Select: minimum first-seen distance, m (paper: 5).")
    ] = None,
    variance: Annotated[
        str | None, typer.Option(help="Select: elevation variance, eq7 or slope.")
    ] = None,
    rule: Annotated[
        str | None,
        typer.Option(help="Select: what --max-sigma bounds, elevation (slope-aware) or ellipse."),
    ] = None,
    fmt: Annotated[str, typer.Option("--format", help="Table format: csv or parquet.")] = "csv",
    images: Annotated[
        bool,
        typer.Option(
            help="When the log has images/ (PNG + timestamps.csv), track them with the "
            "camera front-end and use those tracks instead of the observations table."
        ),
    ] = True,
) -> None:
    """Fuse a measurement log in iSAM2 (GPS with bias states, odometry, camera landmarks),
    select landmarks by the paper's rules (1-sigma, first-seen distance; Eq 7 variance) and
    write the trajectory and landmark tables, samples.csv (x, y, z, z_var: the input of
    glacimap reconstruct) and localize_summary.json into --out."""
    from terrain.atomic import atomic_path, ensure_writable_dir

    from ..config import load_scenario
    from ..export._files import staged_folder
    from ..pipeline import (
        landmark_table,
        localization_summary,
        localize_log,
        samples_table,
        select_samples,
        trajectory_table,
    )

    if fmt not in FORMATS:
        raise bad_input("--format", fmt, " or ".join(FORMATS), "pick one")
    select = {
        key: value
        for key, value in (
            ("max_sigma_m", max_sigma),
            ("min_first_seen_distance_m", min_first_seen),
            ("variance", variance),
            ("rule", rule),
        )
        if value is not None
    }
    scenario = load_scenario(config, {"select": select} if select else None)
    sel_cfg = scenario["select"]  # checked here, before the (long) localization
    if sel_cfg["variance"] not in ("eq7", "slope"):
        raise bad_input("--variance", sel_cfg["variance"], "eq7 or slope", "")
    if sel_cfg["rule"] not in ("elevation", "ellipse"):
        raise bad_input("--rule", sel_cfg["rule"], "elevation or ellipse", "")
    for opt, key in (
        ("--max-sigma", "max_sigma_m"),
        ("--min-first-seen", "min_first_seen_distance_m"),
    ):
        if not (math.isfinite(sel_cfg[key]) and sel_cfg[key] >= 0):
            raise bad_input(opt, sel_cfg[key], "a finite distance >= 0 (m)", "e.g. 0.5 / 5")
    log = read_log_folder(log_dir, images)  # a field folder's images/: tracked by its reader
    front_end = (log.ingest or {}).get("front_end") or None
    field = (log_dir / "survey.json").is_file()
    if not field and images and (log_dir / "images").is_dir():
        log, front_end = _track_images(log, log_dir / "images")
    out_dir = ensure_writable_dir(out)
    with count_bar(console) as bar:
        task = bar.add_task("iSAM2 keyframes", total=log.n_keyframes)
        loc = localize_log(log, scenario, progress=lambda k, n: bar.update(task, completed=k))
    sel = select_samples(loc, scenario)
    summary = localization_summary(loc, sel)
    names = {k: v.format(fmt=fmt) for k, v in FILES.items()}
    with staged_folder(out_dir) as tmp:
        _write_table(trajectory_table(loc), tmp / names["trajectory"], fmt)
        _write_table(landmark_table(loc, sel), tmp / names["landmarks"], fmt)
        _write_table(samples_table(sel), tmp / names["samples"], "csv")
        record = {
            "log": str(log_dir),
            "crs": log.crs,
            "origin": [float(v) for v in log.origin],
            "seed": log.seed,
            "settings": {"localize": scenario["localize"], "select": sel.settings},
            **summary,
        }
        if front_end is not None:  # the camera front-end ran on the log's images/
            record["front_end"] = front_end
        with atomic_path(tmp / names["summary"]) as path:
            path.write_text(json.dumps(record, indent=2))
    _print_counts(summary, [out_dir / n for n in names.values()])
    console.print(
        f"next: glacimap reconstruct {out_dir / names['samples']} (its crs column names "
        "the CRS; z_var: Eq 7 elevation variance, m^2)"
    )
