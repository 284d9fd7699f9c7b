"""``glacimap simulate``: drive a survey plan over a true DEM and write the measurement log."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from terrain.errors import InputError, bad_input

from ._progress import count_bar

console = Console()

#: Formats of the log tables (factorgraph.log.write_log), and "field": the files a rover brings
#: back (factorgraph.write_field_log: GPS file, odometry/tilt/tracks CSV, camera YAML).
FORMATS = ("csv", "parquet", "field")
GPS_FORMATS = ("nmea", "gpx", "rtklib")
#: Keys a plan file must have (survey.SurveyPlan.to_dict, as ``glacimap plan`` writes it).
PLAN_KEYS = ("waypoints", "swath", "pattern", "params", "samples", "sample_swath")
PLAN_KEYS += ("swath_offsets", "heading_deg", "origin")


def read_plan(path: Path):
    """A :class:`survey.SurveyPlan` from a ``plan.json`` written by ``glacimap plan``."""
    from survey import SurveyPlan

    if not path.is_file():
        raise bad_input("--plan", str(path), "an existing plan.json", "run glacimap plan first")
    try:
        data: Any = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise bad_input("--plan", path.name, "a JSON plan (glacimap plan)", str(exc)) from exc
    if not isinstance(data, dict):
        raise bad_input("--plan", type(data).__name__, "a JSON object", "run glacimap plan")
    missing = [k for k in PLAN_KEYS if k not in data]
    if missing:
        raise bad_input(
            f"{path.name} keys", sorted(data), f"a plan with {missing} too", "run glacimap plan"
        )
    try:
        return SurveyPlan.from_dict(data)
    except InputError as exc:
        raise InputError(f"{path.name}: {exc}") from exc
    except (TypeError, ValueError) as exc:
        raise bad_input(path.name, str(exc), "a plan written by glacimap plan", "") from exc


def _print_log(log, plan, out_dir: Path, fmt: str) -> None:
    from pyproj import CRS

    crs = CRS.from_user_input(log.crs)  # a WKT without EPSG code is pages long: its name
    code = crs.to_epsg()
    table = Table(
        title=f"simulated traverse — seed {log.seed} — {f'EPSG:{code}' if code else crs.name}"
    )
    table.add_column("quantity")
    table.add_column("value", justify="right")
    rows = {
        "plan": f"{plan.pattern}, {plan.n_swaths} swaths, {plan.path_length:.0f} m",
        "keyframes": f"{log.n_keyframes}",
        "driving time (s)": f"{log.duration_s:.0f}",
        "GPS fixes": f"{log.gps_k.size}",
        "odometry steps": f"{len(log.odometry)}",
        "feature observations": f"{log.obs_k.size}",
        "feature tracks": f"{len(set(log.obs_id.tolist()))}",
        "local origin (E, N)": f"{log.origin[0]:.1f}, {log.origin[1]:.1f}",
    }
    for k, v in rows.items():
        table.add_row(k, v)
    console.print(table)
    console.print(f"wrote the measurement log ({fmt}) into {out_dir}")


#: Render + track seconds per frame (default front-end, 640 x 480), measured on 2 cores.
IMAGE_SECONDS_PER_FRAME = 0.45
#: Frames of the default survey (4 swaths over the embedded 600 m site).
DEFAULT_SURVEY_FRAMES = 1386
#: Above this many frames ``--camera images`` warns (twice the default survey).
IMAGE_FRAMES_WARN = 2 * DEFAULT_SURVEY_FRAMES


def say_image_frames(console: Console, frames: float) -> None:
    """Before rendering: how many frames, about how long, and a warning past twice the
    default survey's (``glacimap simulate`` and ``glacimap run --camera images``)."""
    # ~0.45 s per 640 x 480 frame to render and track on one of the 2 reference cores
    # (docs/vision.md: 1,386 frames in 11.8 min at load 6-9, 9.9 min at load 2-7)
    minutes = frames * IMAGE_SECONDS_PER_FRAME / 60.0
    console.print(f"{frames:.0f} frames to render and track: about {minutes:.0f} min")
    if frames > IMAGE_FRAMES_WARN:
        console.print(
            f"[yellow]warning: {frames:.0f} frames is {frames / DEFAULT_SURVEY_FRAMES:.1f} x the "
            "default survey's; set \\[site] bounds to a rover-sized window or fewer "
            "\\[plan] n_swaths for a shorter run[/yellow]"
        )


def _simulate_images(scenario, truth, plan, scene: str, images_dir: Path):
    """The log of ``plan`` seen through rendered frames (written into ``images_dir``) and
    tracked by the default front-end (:func:`factorgraph.vision.simulate_images`)."""
    from factorgraph.sensors import SensorSuite
    from factorgraph.vision import SCENES, simulate_images, vision_sensors

    sensors = vision_sensors(SensorSuite.from_dict(scenario["sensors"]))
    frames = plan.path_length / (sensors.speed_mps * sensors.keyframe_dt_s)
    say_image_frames(console, frames)
    with count_bar(console) as bar:
        task = bar.add_task(f"rendering and tracking ({scene})", total=round(frames))
        run = simulate_images(
            truth,
            plan,
            sensors,
            int(scenario["seed"]),
            SCENES[scene],
            images_dir=images_dir,
            progress=lambda k, n: bar.update(task, total=n, completed=k),
        )
    tr = run.tracks
    console.print(
        f"front-end: {tr.n_tracks} tracks of >= {tr.params.min_track_length} views, "
        f"{len(tr.k) / run.log.n_keyframes:.1f} per keyframe; rejected: "
        + ", ".join(f"{k} {v}" for k, v in sorted(tr.counts.items()))
        + f"; render {run.timings['render_s']:.0f} s, track {run.timings['track_s']:.0f} s"
    )
    return run.log


def _check_camera(camera: str, scene: str, out: Path) -> None:
    """``--camera`` / ``--scene`` checked before the (long) simulation."""
    if camera not in ("tracks", "images"):
        raise bad_input("--camera", camera, "tracks or images", "pick one")
    if camera == "images":
        from factorgraph.vision import SCENES

        if scene not in SCENES:
            raise bad_input("--scene", scene, f"one of {sorted(SCENES)}", "pick one")
        if (Path(out) / "images").exists():
            raise bad_input(
                "--out", str(Path(out) / "images"), "no frames of an earlier run", "remove it"
            )


def simulate_command(
    config: Annotated[
        Path | None, typer.Option("--config", help="Scenario TOML (default: embedded).")
    ] = None,
    plan: Annotated[
        Path | None,
        typer.Option(
            help="Plan file written by glacimap plan (default: the scenario's plan table)."
        ),
    ] = None,
    out: Annotated[Path, typer.Option(help="Output folder of the log.")] = Path("out/log"),
    fmt: Annotated[
        str,
        typer.Option(
            "--format",
            help="csv or parquet (glacimap-log/1 tables), or field: a rover's own files "
            "(docs/field-format.md).",
        ),
    ] = "csv",
    gps_format: Annotated[
        str, typer.Option("--gps-format", help="GPS file of --format field: nmea, gpx, rtklib.")
    ] = "nmea",
    seed: Annotated[int | None, typer.Option(help="Override the scenario's seed.")] = None,
    epoch: Annotated[
        int | None,
        typer.Option(help="Override the scenario's change.epoch: 2 = the site after its change."),
    ] = None,
    camera: Annotated[
        str | None,
        typer.Option(
            help="tracks: ideal simulated feature tracks; images: render the frames (vision "
            "camera preset) into OUT/images and track them (docs/vision.md). Default: the "
            "scenario's [field] camera (tracks)."
        ),
    ] = None,
    scene: Annotated[
        str | None,
        typer.Option(
            help="With --camera images: sunny_snow, sunny_dirty_ice, ... Default: the "
            "scenario's [field] scene (sunny_snow)."
        ),
    ] = None,
) -> None:
    """Simulate a rover traverse: drive the scenario's plan (or --plan FILE) over the
    scenario's true DEM with its sensors (GPS with Gauss-Markov bias, odometry with drift,
    camera features) and write the measurement log (meta.json + keyframes, odometry, gps,
    observations, landmarks tables) into --out, ready for glacimap localize; with
    --format field, the files a rover brings back instead (GPS as NMEA / GPX / RTKLIB,
    odometry, tilt and tracks CSV, camera.yaml, survey.json; no truth)."""
    from factorgraph.log import write_log
    from terrain.atomic import ensure_writable_dir
    from terrain.grid import check_same_crs

    from ..config import load_scenario
    from ..epochs import survey_scenario
    from ..export._files import staged_folder
    from ..pipeline import make_plan, make_truth, simulate_log

    if fmt not in FORMATS:
        raise bad_input("--format", fmt, " or ".join(FORMATS), "pick one")
    if gps_format not in GPS_FORMATS:
        raise bad_input("--gps-format", gps_format, " or ".join(GPS_FORMATS), "pick one")
    overrides: dict[str, Any] = {"seed": seed} if seed is not None else {}
    if epoch is not None:
        overrides["change"] = {"epoch": epoch}
    scenario = load_scenario(config, overrides or None)
    camera = camera or scenario["field"]["camera"]  # one TOML, one survey: as glacimap run
    scene = scene or scenario["field"]["scene"]
    _check_camera(camera, scene, out)
    survey_plan = read_plan(plan) if plan is not None else None
    out_dir = ensure_writable_dir(out)
    with console.status("building the true terrain..."):
        truth = make_truth(scenario)
    if "site_dem" in truth.attrs:  # kind = "dem": say which CRS and bounds were chosen
        s = json.loads(truth.attrs["site_dem"])
        console.print(
            f"site from {s['dem']}: {s['site_crs']} ({s['site_crs_from']}), bounds "
            f"{s['bounds']}, {s['resampling']} from {s['dem_cell_m']:g} m cells, "
            f"{s['nodata_cells_filled']} nodata cells filled"
        )
    scenario = survey_scenario(scenario)  # epoch 2: surveyed with seed + [change] seed_offset
    if survey_plan is None:
        survey_plan = make_plan(scenario, truth)
    else:
        from terrain import Grid

        check_same_crs(survey_plan.crs, Grid.from_dataarray(truth).crs, "--plan", "site")
    with staged_folder(out_dir) as tmp:
        if camera == "images":  # frames into OUT/images, tracks from the front-end
            log = _simulate_images(scenario, truth, survey_plan, scene, tmp / "images")
        else:
            with console.status(f"driving {survey_plan.path_length:.0f} m..."):
                log = simulate_log(scenario, truth, survey_plan)
        if fmt == "field":
            from factorgraph.field import write_field_log

            write_field_log(log, tmp, gps_format=gps_format)
        else:
            write_log(log, tmp, fmt=fmt)
        written = sorted(p.name for p in tmp.iterdir())
    other = {"csv": "parquet", "parquet": "csv"}.get(fmt)
    for name in written:  # a stale table in the other format would be read first
        if other and name.endswith(f".{fmt}"):
            (out_dir / name).with_suffix(f".{other}").unlink(missing_ok=True)
    for stale in ({"gps.nmea", "gps.gpx", "gps.pos"} - set(written)) if fmt == "field" else ():
        (out_dir / stale).unlink(missing_ok=True)  # one GPS file per field folder
    _print_log(log, survey_plan, out_dir, fmt)
