"""``glacimap process``: a real survey's files -> the certified products, no truth anywhere.

ingest (a rover's field folder or a ``glacimap-log/1`` folder) -> localize (iSAM2, with
ground control when given) -> select (Eq 7) -> reconstruct (TerrainGP with the terrain
layer's defaults and the satellite DEM file as prior mean, :class:`terrain.RasterMean`) ->
certify (independent checkpoints; the 1-sigma checked on held-out samples) -> export ->
report. ``glacimap run`` writes its simulated survey as such files and calls
:func:`process` (docs/pipeline.md).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from contextlib import contextmanager
from copy import copy
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from factorgraph.log import MeasurementLog
from terrain import RasterMean
from terrain.atomic import atomic_path
from terrain.errors import InputError, bad_input

from .breaklines_io import is_search, read_breaklines, scenario_lines, with_breaklines
from .certify import require_checkpoints_on
from .config import load_scenario
from .export._files import output_folder, previous_products, remove_stale, staged_folder
from .prior_reading import choose_reading, prior_reading, reading_record
from .provenance import input_record, split_timings
from .stages import (
    certify_stage,
    localization_summary,
    localize_stage,
    map_grid,
    reconstruct_selection,
    select_stage,
)

__all__ = ["PROCESS_STAGES", "ProcessResult", "ingest", "prior_mean", "process"]

PROCESS_STAGES = ("ingest", "localize", "select", "reconstruct", "certify", "export")


@dataclass(repr=False)
class ProcessResult:
    """What :func:`process` made: products on disk plus the in-memory objects.

    Attributes
    ----------
    out : pathlib.Path
        The output folder.
    settings : dict
        The settings used (the scenario TOML's tables, validated).
    timings : dict of str to float
        Wall-clock seconds per stage (``ingest``, ``localize``, ...).
    summary : dict
        What ``summary.json`` holds: ``seed``, ``certificate`` (the certificate's dict:
        ``accuracy`` RMSE / bias in m against the checkpoints, ``heldout_calibration``
        coverages as fractions, verdicts per standard), ``timings_s``, ``products``.
    objects : dict
        In-memory results: ``log``, ``localization``, ``selection``, ``reconstruction``
        (its ``.product`` is the map: an ``xarray.Dataset`` with ``elevation``,
        ``elevation_std`` and ``elevation_std_relative`` in m on (y, x)), ``grid``,
        ``control``, ``checkpoints``.
    products : list of str
        File names written into ``out``.
    removed : list of str
        Files of an earlier run into the same ``out`` that this one removed.
    """

    out: Path
    settings: dict[str, Any]
    timings: dict[str, float] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)
    objects: dict[str, Any] = field(default_factory=dict)
    #: Files written into ``out`` (``summary.json["products"]``), and those of an earlier run
    #: into the same ``out`` that this one removed (:func:`.export._files.remove_stale`).
    products: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)

    def __repr__(self) -> str:
        """One line a notebook can read: folder, seed, the certified numbers, time."""
        cert = self.summary.get("certificate") or {}
        parts = [f"out={str(self.out)!r}", f"seed={self.summary.get('seed')}"]
        acc = cert.get("accuracy")
        if acc:
            parts.append(
                f"RMSE vs {acc['n']} checkpoints {acc['rmse_m']:.3f} m "
                f"(bias {acc['bias_m']:+.3f} m)"
            )
        held = cert.get("heldout_calibration") or {}
        if held.get("map_coverage_68") is not None:
            parts.append(
                f"held-out coverage of the map 68/95 % = {100 * held['map_coverage_68']:.1f}/"
                f"{100 * held['map_coverage_95']:.1f} %"
            )
        parts.append(f"{len(self.products)} files")
        if self.timings:
            parts.append(f"{sum(self.timings.values()):.1f} s")
        return f"{type(self).__name__}({', '.join(parts)})"

    @contextmanager
    def stage(self, name: str, notify: Callable[[str, str], None] | None = None):
        """Time the stage ``name`` into :attr:`timings`; ``notify(name, "start" | "done")``."""
        notify = notify or (lambda stage, state: None)
        notify(name, "start")
        t = time.perf_counter()
        yield
        self.timings[name] = round(time.perf_counter() - t, 3)
        notify(name, "done")


def ingest(
    log: Any, crs: Any = None, images: bool = True, on_frames: Any = None
) -> tuple[MeasurementLog, dict[str, Any]]:
    """A measurement log from a :class:`MeasurementLog`, a ``glacimap-log/1`` folder
    (``meta.json``) or a rover's field folder (``survey.json``, docs/field-format.md).

    A folder with camera frames (``images/``: PNG + ``timestamps.csv``) gets its feature
    tracks from the OpenCV front-end (:func:`factorgraph.vision.track_log_frames`) unless
    ``images`` is False (``on_frames(k, K)`` while it tracks). Returns the log and the ingest
    report (what was read, what was skipped and why; ``front_end``: what the front-end
    did)."""
    from factorgraph.field import read_field_log
    from factorgraph.log import read_log

    if isinstance(log, MeasurementLog):
        return log, dict(getattr(log, "ingest", None) or {})
    folder = Path(log)
    if (folder / "survey.json").is_file():
        mlog, report = read_field_log(folder, crs=crs, images=images, progress=on_frames)
        return mlog, report.as_dict()
    if (folder / "meta.json").is_file():
        mlog = read_log(folder)
        report = {"format": "glacimap-log/1", **dict(mlog.ingest or {})}
        if images and (folder / "images").is_dir():
            from factorgraph.vision import track_log_frames

            mlog, report["front_end"] = track_log_frames(
                mlog, folder / "images", progress=on_frames
            )
        return mlog, report
    raise bad_input(
        "LOG_DIR",
        str(folder),
        "a field folder with survey.json or a glacimap-log/1 folder with meta.json",
        "see docs/field-format.md, or write one with glacimap simulate --format field",
    )


def prior_mean(prior: Any, settings: dict[str, Any]) -> Any:
    """The GP prior mean: ``RasterMean(prior)`` (a + b * DEM fitted by GLS) with the
    ``[prior]`` settings (``cells``: ``"auto"``, the paper's triangulated 8 x 8 mean unless
    the DEM is at least twice finer, ``[ny, nx]`` or ``[]`` for its own; ``resampling``), or
    a constant mean when no prior is given. A DEM read from a file is labelled by its file
    name (its ``repr`` and the products' ``mean_function``), not its absolute path."""
    if prior is None:
        return "constant"
    if isinstance(prior, RasterMean):  # a copy: the caller's object keeps its label
        return _named_by_file(copy(prior))
    if isinstance(prior, str | os.PathLike) and not Path(prior).is_file():
        raise bad_input(
            "--prior",
            str(prior),
            "an existing DEM file (GeoTIFF or any GDAL raster)",
            "check the path",
        )
    cfg = settings.get("prior", {})
    cells = cfg.get("cells", "auto")
    if not (isinstance(cells, str) and cells == "auto"):  # a list: [8, 8], or [] (own cells)
        cells = tuple(int(c) for c in cells) or None
    mean = RasterMean(
        prior,
        resampling=cfg.get("resampling", "bilinear"),
        cells=cells,
        coarse=cfg.get("coarse", "mesh"),
    )
    return _named_by_file(mean)


def _named_by_file(mean: RasterMean) -> RasterMean:
    """Label a file-backed RasterMean by its file name: provenance names the file, not where
    it was read, so the products' bytes do not depend on the folder (toolkit.provenance);
    the file's SHA-256 is in the product's ``inputs`` attribute."""
    if mean.source.path is not None:
        mean.source = replace(mean.source, label=Path(mean.source.path).name)
    return mean


def _survey_dates(samples: Any, ingest_report: dict[str, Any]) -> dict[str, str]:
    """The map's ``survey_date`` / ``survey_period`` (UTC): the landmarks' times on the rover
    clock plus the field folder's clock offset (``utc = t_rover + clock_offset_s``); ``{}``
    for a log without one (a simulated log's clock is not UTC)."""
    from terrain.mass_balance import survey_date_attrs

    t_s, offset = samples.extra.get("t_s"), ingest_report.get("clock_offset_s")
    if t_s is None or offset is None:
        return {}
    return survey_date_attrs(np.asarray(t_s, float) + float(offset))


def _control_and_checkpoints(control: Any, checkpoints: Any, log: MeasurementLog):
    from factorgraph.control import ControlPoints, check_independent
    from factorgraph.control_io import read_control

    from .certify_io import Checkpoints, read_checkpoints
    from .point_files import point_format, read_control_layer

    ctrl = control
    if control is not None and not isinstance(control, ControlPoints):
        layer = point_format(control) == "vector"  # a surveyor's GeoPackage / Shapefile
        ctrl = read_control_layer(control) if layer else read_control(control)
    if ctrl is not None:
        ctrl = ctrl.to_crs(log.crs)
    cps = checkpoints
    if checkpoints is not None and not isinstance(checkpoints, Checkpoints):
        cps = read_checkpoints(checkpoints)
    if ctrl is not None and cps is not None:
        check_independent(ctrl, cps)  # ASPRS 2023: checkpoints never double as control
    return ctrl, cps


def process(
    log: Any,
    prior: Any = None,
    control: Any = None,
    checkpoints: Any = None,
    config: Any = None,
    out: str | Path = "out/process",
    bounds: tuple[float, float, float, float] | None = None,
    on_stage: Callable[[str, str], None] | None = None,
    on_progress: Callable[[int, int], None] | None = None,
    truth: Any = None,
    truth_path: Any = None,
    images: bool = True,
    on_frames: Callable[[int, int], None] | None = None,
    breaklines: Any = None,
    breakline_width: float | str = "auto",
    breakline_taper: float | str = "auto",
) -> ProcessResult:
    """Process a survey into certified products in ``out``.

    Parameters
    ----------
    log : path or MeasurementLog
        A rover's field folder (``survey.json``), a ``glacimap-log/1`` folder or a log.
    prior : path, rasterio dataset, xarray.DataArray or RasterMean, optional
        The satellite DEM (any CRS; must cover the map): the GP's prior mean, its vertical
        offset and scale fitted; with ``[prior] as = "data"`` its cells as samples beside
        the survey's (:func:`terrain.dem_as_data.dem_as_data`) under a constant mean. None:
        a constant mean.
    control : path or ControlPoints, optional
        Ground control (CSV, any CRS; factorgraph.read_control).
    checkpoints : path or Checkpoints, optional
        Independent checkpoints (CSV, any CRS) for the certificate; never the same points as
        the control (an error naming the point).
    config : path or dict, optional
        A scenario TOML (or its dict) for ``seed``, ``[localize]``, ``[select]``,
        ``[reconstruct]``, ``[prior]``, ``[certify]``, ``[export]``; default: the embedded one.
    out : path
        Output folder; products appear all at once (staged), or none on failure.
    bounds : (west, south, east, north), optional
        Map extent in the log's CRS (m); default: the selected landmarks' bounding box.
    on_stage, on_progress : callable, optional
        ``on_stage(stage, "start" | "done")``; ``on_progress(k, K)`` during localization.
    truth, truth_path : xarray.DataArray, ndarray of shape (n, 3), optional
        Simulation only: the report's error map and the true path layer. Nothing else reads
        them.
    images : bool
        When the log folder has camera frames (``images/``), track them with the OpenCV
        front-end and use those tracks (default); False: the folder's tracks table.
    on_frames : callable, optional
        ``on_frames(k, K)`` while the front-end tracks the frames (ingest).
    breaklines : path, sequence of (k, 2) arrays or "auto", optional
        Lines the ground steps across (an ice cliff, a moraine's edge; one that stops inside
        the survey has its step die out towards that end): a vector file (reprojected to the
        map's CRS from the CRS it declares; WKT in the map's CRS) or vertex arrays in the
        map's CRS (``terrain.BreaklineMean`` on the prior mean; heights fitted); ``"auto"``:
        found in the selected landmarks (``terrain.find_breaklines``; what was found and
        dropped in the certificate's ``inputs.breakline_search``). None: the settings'
        ``[reconstruct] breaklines`` (with their width and taper; ``""``: none).
    breakline_width : float or "auto"
        Scale of each step's logistic, m; ``"auto"``: each line's own, chosen by the fit.
    breakline_taper : float or "auto"
        Length a step dies out over before an end of its line inside the survey, m;
        ``"auto"``: each line's own, chosen by the fit.

    Returns
    -------
    ProcessResult
        The products' folder and names, the certificate (``.summary["certificate"]``), the
        stage timings (s) and the in-memory map (``.objects["reconstruction"].product``:
        ``elevation``, ``elevation_std``, ``elevation_std_relative``, m).
    """
    settings = config if isinstance(config, dict) else load_scenario(config)
    lines = (breaklines, breakline_width, breakline_taper)
    if breaklines is None:  # the scenario's [reconstruct] breaklines, width and taper
        lines = scenario_lines(settings)
    with output_folder(out) as folder:
        return _process(
            log, prior, control, checkpoints, settings, folder, bounds, on_stage, on_progress,
            truth, truth_path, images, on_frames, lines,
        )  # fmt: skip


def _file_or_none(source: Any) -> Any:
    """``source`` when it names a file (its provenance is recorded), else None."""
    return source if isinstance(source, str | os.PathLike) else None


def _process(
    log, prior, control, checkpoints, settings, out, bounds, on_stage, on_progress, truth,
    truth_path, images=True, on_frames=None, breaklines=(None, "auto", "auto"),
) -> ProcessResult:  # fmt: skip
    seed = int(settings["seed"])
    res = ProcessResult(out=out, settings=settings)
    before = previous_products(out)

    def stage(name: str):
        return res.stage(name, on_stage)

    with stage("ingest"):
        mlog, ingest_report = ingest(log, images=images, on_frames=on_frames)
        ctrl, cps = _control_and_checkpoints(control, checkpoints, mlog)
        resolution = float(settings["reconstruct"]["resolution_m"])
        if cps is not None and bounds is not None:  # on the map? known before localizing
            require_checkpoints_on(cps, map_grid(bounds, resolution, mlog.crs))
        # a step across each breakline (a vector file, read in the map's CRS, or vertices)
        # (``auto``: found in the selected samples, below)
        search = is_search(breaklines[0])
        reading = prior_reading(prior, settings)  # mean, data (its cells as samples) or auto
        dem_mean = None if reading == "data" else prior_mean(prior, settings)
        # which files made the map, by name and SHA-256 (every product's metadata)
        log_record = None if isinstance(log, MeasurementLog) else input_record("log", log)
        prior_record = input_record("prior", prior)
        files = [
            r
            for r in (
                log_record,
                prior_record,
                input_record("control", control),
                input_record("checkpoints", checkpoints),
                input_record("breaklines", None if search else _file_or_none(breaklines[0])),
            )
            if r is not None
        ]
        if not search and _file_or_none(breaklines[0]) is not None:  # read now: fails fast
            read = read_breaklines(Path(breaklines[0]), mlog.crs)
            breaklines = (read, *breaklines[1:])
    with stage("localize"):
        loc = localize_stage(mlog, settings, control=ctrl, progress=on_progress)
    with stage("select"):
        sel = select_stage(loc, settings)
        if sel.samples.n < 3:
            raise InputError(
                f"only {sel.samples.n} landmarks passed the selection (counts: {sel.counts}); "
                "a map needs at least 3: check the camera tracks and the [select] settings"
            )
    with stage("reconstruct"):
        grid = map_grid(bounds, resolution, mlog.crs, sel.samples)
        if cps is not None and bounds is None:  # the grid is new: placed before the fit
            require_checkpoints_on(cps, grid)
        folds = int(settings["certify"]["heldout_folds"])
        found: list[str] = []
        choice, unchosen = None, None
        if reading == "auto":  # the reading the held-out landmarks map better (no steps)
            choice = choose_reading(prior, dem_mean, sel.samples, grid, settings, seed)
            if isinstance(choice, str):  # too few landmarks to hold out: the mean, said
                choice, unchosen, reading = None, choice, "mean"
            else:
                reading = choice.choice
        mean = base = "constant" if reading == "data" else dem_mean
        if search:  # steps found in the selected samples (terrain.find_breaklines)
            mean = with_breaklines(mean, *breaklines, notes=found, samples=sel.samples)
        else:  # the vector file's steps (read at ingest) or given vertices, map's CRS
            mean = with_breaklines(mean, *breaklines, crs=mlog.crs)
        samples, dem_note = sel.samples, None
        if reading == "data":  # co-kriged with the survey (terrain/dem_as_data.py)
            from terrain.dem_as_data import dem_as_data

            dem = prior.source if isinstance(prior, RasterMean) else prior
            samples, dem_note = dem_as_data(dem, sel.samples, grid.bounds)
        # the choice's own fit of that reading, unless steps joined its mean
        fitted = choice.models[reading] if choice is not None and mean is base else None
        rec = reconstruct_selection(
            sel, grid, mean, settings, seed, folds, samples=samples, fitted=fitted
        )
        if dem_note is not None:
            rec.product.attrs["prior_as_data"] = dem_note.note()
        if choice is not None:
            rec.product.attrs["prior_reading"] = reading_record(choice)
        if unchosen:  # a certificate warning (certify_stage states the prior's notes)
            note = rec.product.attrs.get("prior_note")
            rec.product.attrs["prior_note"] = "; ".join(n for n in (note, unchosen) if n)
        rec.product.attrs["inputs"] = json.dumps(
            [{k: r[k] for k in ("role", "name", "sha256")} for r in files]
        )
        rec.product.attrs.update(_survey_dates(sel.samples, ingest_report))
    with staged_folder(out) as tmp_out:
        from .products import write_products

        with stage("certify"):
            cert = certify_stage(rec, cps, settings, seed)
            # wall-clock seconds go to summary.json only: a certificate is the same bytes
            # for the same inputs and seed (toolkit.provenance)
            cert["localization"], loc_times = split_timings(localization_summary(loc, sel))
            cert["ingest"] = ingest_report
            for w in ingest_report.get("warnings", []):  # e.g. a map CRS far from the site
                cert.setdefault("warnings", []).append(w)
            cert["inputs"] = {
                "log": log_record["name"] if log_record else "in memory",
                "prior": None if prior_record is None else prior_record["name"],
                "control": None if ctrl is None else f"{ctrl.n} points ({ctrl.source})",
                "checkpoints": None if cps is None else str(getattr(cps, "source", "")),
                "files": files,
            }
            if found:  # --breaklines auto: what the search found, and dropped and why
                cert["inputs"]["breakline_search"] = found
            if ctrl is not None:  # which control the graph used: stop / target, and why not
                c = loc.control or {}
                used = [f"{u['id']} {u['kind']}" for u in c.get("used", [])]
                unused = [f"{k} {v}" for k, v in c.get("unused", {}).items()]
                cert["inputs"]["control"] += f"; used: {', '.join(used) or 'none'}" + (
                    f"; unused: {', '.join(unused)}" if unused else ""
                )
            stops = mlog.control_id is not None and bool((mlog.control_id != "").any())
            if stops and ctrl is None:
                cert.setdefault("warnings", []).append(
                    "the log has stops on control points (stops.csv) but no control file was "
                    "given: the stops were not used (pass --control)"
                )
        with stage("export"):
            truth_on_grid = None
            if truth is not None:
                truth_on_grid = truth.interp(x=grid.x, y=grid.y, method="linear")
            write_products(tmp_out, rec, cert, loc, sel, settings, truth_on_grid, truth_path)
            res.products = sorted([p.name for p in tmp_out.iterdir()] + ["summary.json"])
            res.summary = {
                "seed": seed,
                "certificate": cert,
                "timings_s": res.timings,
                "localization_timings_s": loc_times,
                "products": res.products,
            }
            with atomic_path(tmp_out / "summary.json") as tmp:
                tmp.write_text(json.dumps(res.summary, indent=2, default=_json_default))
    res.removed = remove_stale(out, before, res.products)
    res.objects = {
        "log": mlog,
        "localization": loc,
        "selection": sel,
        "reconstruction": rec,
        "grid": grid,
        "control": ctrl,
        "checkpoints": cps,
    }
    return res


def _json_default(o: Any):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
