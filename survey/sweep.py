"""The Monte Carlo of the paper's Fig. 10-11: minimum swaths that meet a mapping class.

For K random terrains (``terrain.random_terrain``, the slowly varying Fig. 7 kind), each
pattern and each swath count: plan, sample the truth along the plan (perfect sensor as in
Fig. 11, optional noise), reconstruct with ``terrain.TerrainGP`` at fixed hyperparameters
(the paper's alpha, gamma), and record RMSE, coverage metrics and path length.

Tasks run on Dask: a ``LocalCluster`` of worker processes by default, or any running
``dask.distributed`` scheduler by address. Each task is a pure function of (configuration,
terrain index, pattern, swath count) with its own seed derived from the one sweep seed, so
results do not depend on the number of workers or the order they finish in. Each result is
committed to ``results.sqlite`` as it arrives; re-running resumes.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from terrain.errors import bad_input

from .store import ResultStore

__all__ = [
    "PATTERNS",
    "SweepConfig",
    "SweepResult",
    "class_limits",
    "run_task",
    "summarize",
    "sweep",
]

PATTERNS = ("lawnmower", "piecewise_continuous")


@dataclass(frozen=True)
class SweepConfig:
    """Everything that defines a sweep (stored with its results; resuming needs it unchanged).

    Parameters
    ----------
    n_terrains : int
        Random terrains K (the paper: 100).
    patterns : tuple of str
        Survey patterns, from :data:`PATTERNS`.
    swaths : tuple of int
        Swath counts N to try (the paper: 1-8).
    bounds : tuple of float
        Survey region (west, south, east, north), m, in ``crs`` (default: the paper's
        600 m x 600 m site near Mendenhall Glacier, UTM 8N).
    relief : float
        Max - min elevation of every random terrain, m (the paper: 25 m).
    resolution : float
        Cell size of the truth and the reconstruction, m.
    spacing : float
        Distance between samples along the path, m.
    noise : float
        Elevation noise 1-sigma of each sample, m (0: the paper's perfect sensor).
    alpha, gamma : float
        The paper's fixed hyperparameters (Section II-D: 10 and 315).
    gamma_reading : str
        ``"lengthscale"`` (the prose: l = gamma m) or ``"squared_lengthscale"`` (Eq 1
        literally: l = sqrt(gamma) m); see ``SquaredExponential.from_paper``.
    nugget : float
        Fixed nugget, m^2: numerical regularization of the noise-free case.
    fit_hyperparameters : bool
        Fit kernel variance, length scale and nugget per task by Eq 9 (on at most 400
        samples), starting from the paper's values, instead of keeping them fixed: slower,
        but the 1-sigma maps are then calibrated (the fixed values are over-confident).
    seed : int
        The one seed; every task's seed derives from it.
    """

    n_terrains: int = 100
    patterns: tuple[str, ...] = PATTERNS
    swaths: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7, 8)
    bounds: tuple[float, float, float, float] = (526000.0, 6475000.0, 526600.0, 6475600.0)
    crs: str = "EPSG:32608"
    relief: float = 25.0
    resolution: float = 10.0
    spacing: float = 10.0
    noise: float = 0.0
    alpha: float = 10.0
    gamma: float = 315.0
    gamma_reading: str = "lengthscale"
    nugget: float = 1e-4
    fit_hyperparameters: bool = False
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "patterns", tuple(self.patterns))
        object.__setattr__(self, "swaths", tuple(int(n) for n in self.swaths))
        object.__setattr__(self, "bounds", tuple(float(b) for b in self.bounds))
        if int(self.n_terrains) < 1:
            raise bad_input("n_terrains", self.n_terrains, ">= 1", "e.g. --terrains 100")
        unknown = [p for p in self.patterns if p not in PATTERNS]
        if unknown or not self.patterns:
            raise bad_input("patterns", self.patterns, f"a non-empty subset of {PATTERNS}", "")
        if not self.swaths or min(self.swaths) < 1:
            raise bad_input("swaths", self.swaths, "swath counts >= 1", "e.g. 1 2 3 4")
        for name in ("relief", "resolution", "spacing", "alpha", "gamma"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise bad_input(name, v, "a positive number", "")
        if not (np.isfinite(self.noise) and self.noise >= 0):
            raise bad_input("noise", self.noise, "a 1-sigma >= 0 in m", "")
        if not (np.isfinite(self.nugget) and self.nugget >= 0):
            raise bad_input("nugget", self.nugget, "a variance >= 0 in m^2", "")
        if self.gamma_reading not in ("lengthscale", "squared_lengthscale"):
            raise bad_input(
                "gamma_reading", self.gamma_reading, '"lengthscale" or "squared_lengthscale"', ""
            )
        self.grid()  # validates bounds, resolution and CRS

    def grid(self):
        from terrain import Grid

        return Grid.from_bounds(self.bounds, self.resolution, crs=self.crs)

    def tasks(self) -> list[tuple[int, str, int]]:
        """Every (terrain, pattern, n_swaths), in a fixed order."""
        return [
            (k, p, n) for k in range(self.n_terrains) for p in self.patterns for n in self.swaths
        ]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def task_key(terrain: int, pattern: str, n_swaths: int) -> str:
    return f"{terrain:05d}/{pattern}/{n_swaths:03d}"


def _seed(*parts: int) -> int:
    """A 63-bit seed from the sweep seed and a task's indices (numpy SeedSequence)."""
    return int(np.random.SeedSequence(list(parts)).generate_state(2, np.uint64)[0] >> 1)


def run_task(config: dict[str, Any], terrain: int, pattern: str, n_swaths: int) -> dict:
    """One Monte Carlo task; a pure function of its arguments (runs on a Dask worker)."""
    from shapely.geometry import box

    from terrain import ElevationSamples, SquaredExponential, TerrainGP, random_terrain
    from terrain.metrics import interval_coverage, rmse
    from terrain.sampling import sample_dem

    from .coverage import centeredness, plan_distributedness, science_centric_coverage
    from .lawnmower import lawnmower
    from .piecewise import piecewise_continuous

    cfg = SweepConfig(**config)
    grid = cfg.grid()
    truth = random_terrain(grid, relief=cfg.relief, seed=_seed(cfg.seed, terrain))
    region = box(*cfg.bounds)
    if pattern == "lawnmower":
        plan = lawnmower(region, n_swaths, spacing=cfg.spacing)
    else:
        # The paper's planner senses the terrain gradient in situ: plan on the truth itself.
        plan = piecewise_continuous(
            region, n_swaths, truth, spacing=cfg.spacing, seed=_seed(cfg.seed, terrain, 1, n_swaths)
        )
    # Samples on the outer edge are moved at most half a cell onto the cell-centre box.
    x, y = grid.x, grid.y
    xy = np.column_stack(
        [np.clip(plan.samples[:, 0], x[0], x[-1]), np.clip(plan.samples[:, 1], y[-1], y[0])]
    )
    rng = np.random.default_rng(_seed(cfg.seed, terrain, 2, n_swaths, PATTERNS.index(pattern)))
    z = sample_dem(truth, xy) + cfg.noise * rng.normal(size=len(xy))
    samples = ElevationSamples(xy, z, cfg.noise**2, crs=grid.crs, duplicates="average")
    kernel = SquaredExponential.from_paper(cfg.alpha, cfg.gamma, reading=cfg.gamma_reading)
    if cfg.fit_hyperparameters:  # Eq 9 per task, started at the paper's values
        gp = TerrainGP(
            kernel=kernel,
            mean="constant",
            nugget=max(cfg.nugget, 1e-6),
            nugget_bounds=(1e-6, 1e2),
            n_restarts=0,
            max_fit_samples=400,
            seed=_seed(cfg.seed, terrain, 3, n_swaths),
            method="exact",
        ).fit(samples)
    else:  # the paper's fixed hyperparameters (Section II-D)
        gp = TerrainGP(
            kernel=kernel,
            mean="constant",
            nugget=cfg.nugget,
            nugget_bounds="fixed",
            optimize=False,
            method="exact",
        ).fit(samples)
    mean, std = gp.predict(grid.xy(), return_std=True)
    truth_v = truth.values.ravel()
    centre = np.array([(cfg.bounds[0] + cfg.bounds[2]) / 2, (cfg.bounds[1] + cfg.bounds[3]) / 2])
    beta = plan_distributedness(plan)
    return {
        "rmse": rmse(mean, truth_v),
        "coverage_95": interval_coverage(mean, std, truth_v),
        "path_length": float(plan.path_length),
        "n_samples": int(samples.n),
        "n_merged": int(samples.n_merged),
        "scc": float(science_centric_coverage(xy, grid.xy(), ref=centre)),
        "alpha": float(centeredness(xy, ref=centre, region=region)),
        "beta": float(beta[1]) if isinstance(beta, tuple) else float(beta),
    }


def class_limits(contour_interval_m: float = 2.7432) -> dict[str, float]:
    """RMSE limits (m) for the paper's Class 3 question at a contour interval (default 9 ft),
    under the paper's tables and the real standards, each labelled with its rule."""
    from .standards import list_classes, max_rmse

    ci = contour_interval_m
    ft = ci / 0.3048
    # ASPRS 2014 Table B.7: a contour interval needs RMSE_z <= CI/3 (the 1990 Class 1 rule);
    # the 2023 class is the loosest X-cm class that still guarantees it.
    needed = ci / 3.0
    x_cm = max(
        (c for c in list_classes("asprs2023") if c.max_rmse_m <= needed), key=lambda c: c.max_rmse_m
    )
    return {
        f"paper Class 3, {ft:g} ft (Table III, CI/6)": max_rmse("paper", "3", ci),
        f"ASPRS 1990 Class 3 contours, {ft:g} ft (CI)": max_rmse("asprs1990", "3", ci, "contour"),
        f"ASPRS 1990 Class 3 spot heights, {ft:g} ft (CI/2)": max_rmse(
            "asprs1990", "3", ci, "spot"
        ),
        f"ASPRS 2023 {x_cm.name} class ({ft:g} ft contours need RMSEz <= CI/3)": x_cm.max_rmse_m,
    }


@dataclass
class SweepResult:
    """Rows, summary and where they were written."""

    config: SweepConfig
    rows: list[dict[str, Any]]
    summary: dict[str, Any]
    out: Path
    computed: int
    skipped: int
    runs: list[tuple[int, int]] = field(default_factory=list)


def summarize(rows: list[dict[str, Any]], limits: dict[str, float]) -> dict[str, Any]:
    """Mean ± std per (pattern, swaths) and the minimum swaths meeting each RMSE limit.

    ``limits`` maps a label (e.g. ``"paper Class 3 (9 ft)"``) to its largest RMSE, m. A
    swath count meets a limit when the mean RMSE over terrains is at most the limit (the
    paper's Fig. 11, "average RMS error"); ``minimum_swaths_by_median`` uses the median (the
    RMSE distribution over terrains is heavy-tailed), and ``fraction_meeting`` gives the share
    of terrains that meet each limit on their own.
    """
    metrics = ("rmse", "coverage_95", "path_length", "scc", "alpha", "beta", "n_samples")
    table: dict[str, dict[str, dict[str, float]]] = {}
    for pattern in sorted({r["pattern"] for r in rows}):
        table[pattern] = {}
        for n in sorted({r["n_swaths"] for r in rows if r["pattern"] == pattern}):
            sel = [r for r in rows if r["pattern"] == pattern and r["n_swaths"] == n]
            entry: dict[str, float] = {"n_terrains": len(sel)}
            for m in metrics:
                vals = np.array([r[m] for r in sel], dtype=float)
                entry[f"{m}_mean"] = float(np.nanmean(vals)) if np.isfinite(vals).any() else None
                entry[f"{m}_std"] = float(np.nanstd(vals)) if np.isfinite(vals).any() else None
            rm = np.array([r["rmse"] for r in sel])
            entry["rmse_median"] = float(np.median(rm))
            entry["fraction_meeting"] = {k: float(np.mean(rm <= v)) for k, v in limits.items()}
            table[pattern][str(n)] = entry

    def first_meeting(stat: str) -> dict[str, dict[str, int | None]]:
        return {
            label: {
                pattern: next(
                    (
                        int(n)
                        for n, e in sorted(t.items(), key=lambda kv: int(kv[0]))
                        if e[stat] <= limit
                    ),
                    None,
                )
                for pattern, t in table.items()
            }
            for label, limit in limits.items()
        }

    return {
        "limits_m": limits,
        "by_pattern": table,
        "minimum_swaths": first_meeting("rmse_mean"),
        "minimum_swaths_by_median": first_meeting("rmse_median"),
    }


def _client(scheduler: Any, n_workers: int | None):
    """A dask.distributed Client: the given one, one connected to an address, or a new
    LocalCluster of single-threaded worker processes. Returns (client, owned)."""
    from distributed import Client, LocalCluster

    if scheduler is None:
        cluster = LocalCluster(
            n_workers=n_workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=40,
        )
        return Client(cluster), True
    if isinstance(scheduler, Client):
        return scheduler, False
    try:
        return Client(str(scheduler), timeout="5s"), True
    except (OSError, TimeoutError) as exc:
        raise bad_input(
            "--scheduler",
            scheduler,
            "the address of a running dask scheduler",
            "start one with `dask scheduler` (it prints tcp://host:port) or omit --scheduler "
            "to use a local cluster",
        ) from exc


def sweep(
    config: SweepConfig,
    out: str | Path,
    scheduler: Any = None,
    n_workers: int | None = None,
    limits: dict[str, float] | None = None,
    on_progress: Callable[[int, int], None] | None = None,
) -> SweepResult:
    """Run (or resume) a Monte Carlo sweep; results in ``out/results.sqlite``,
    ``out/summary.json`` and figures.

    Parameters
    ----------
    config : SweepConfig
    out : path-like
        Output folder; an existing store made with the same configuration is resumed.
    scheduler : None, str or distributed.Client
        None: a LocalCluster (``n_workers`` processes); ``"tcp://host:port"``: an existing
        scheduler; or a Client.
    limits : dict of str to float, optional
        RMSE limits (m) to find minimum swaths for; default: the paper's Class 3 (0.4572 m).
    on_progress : callable, optional
        Called as ``on_progress(done, total)`` after each committed task.
    """
    from distributed import as_completed

    from terrain.atomic import atomic_path, ensure_writable_dir

    out_dir = ensure_writable_dir(out)
    if limits is None:
        limits = class_limits()
    # Connect before touching the store: a dead scheduler must not leave a store behind.
    client, owned = _client(scheduler, n_workers)
    try:
        with ResultStore(out_dir / "results.sqlite", config.to_dict()) as store:
            done = store.done()
            tasks = config.tasks()
            todo = [t for t in tasks if task_key(*t) not in done]
            total, finished = len(tasks), len(tasks) - len(todo)
            if on_progress:
                on_progress(finished, total)
            cfg = config.to_dict()
            futures = client.map(
                run_task,
                [cfg] * len(todo),
                [t[0] for t in todo],
                [t[1] for t in todo],
                [t[2] for t in todo],
                key=[f"glacimap-sweep-{config.seed}-{task_key(*t)}" for t in todo],
                pure=False,
            )
            index = {f.key: t for f, t in zip(futures, todo, strict=True)}
            for fut in as_completed(futures):
                terrain, pattern, n = index[fut.key]
                store.add(task_key(terrain, pattern, n), terrain, pattern, n, fut.result())
                fut.release()
                finished += 1
                if on_progress:
                    on_progress(finished, total)
            rows = store.rows()
            runs = [tuple(r) for r in store.runs()]
    finally:
        if owned:
            cluster = getattr(client, "cluster", None)
            client.close()
            if cluster is not None:
                cluster.close()
    summary = summarize(rows, limits)
    summary["config"] = config.to_dict()
    with atomic_path(out_dir / "summary.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2, sort_keys=True))
    return SweepResult(
        config,
        rows,
        summary,
        out_dir,
        computed=len(todo),
        skipped=len(tasks) - len(todo),
        runs=runs,
    )
