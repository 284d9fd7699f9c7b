"""Shared benchmark plumbing: run a case in a fresh process (so its peak RSS is its own),
print aligned tables, write JSON atomically."""

from __future__ import annotations

import json
import multiprocessing as mp
import platform
import resource
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


def _child(func: Callable, args: tuple, queue) -> None:
    t0 = time.perf_counter()
    out = func(*args)
    out["wall_s"] = time.perf_counter() - t0
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    queue.put(out)


def in_subprocess(func: Callable, *args: Any) -> dict[str, Any]:
    """Run ``func(*args) -> dict`` in a spawned process; add ``wall_s`` and ``peak_rss_mb``."""
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_child, args=(func, args, queue))
    proc.start()
    out = queue.get()
    proc.join()
    return out


def table(rows: list[dict[str, Any]], columns: list[tuple[str, str, str]]) -> str:
    """Format rows as a fixed-width table; ``columns`` = (key, header, format)."""
    head = "  ".join(f"{h:>{max(len(h), 9)}}" for _, h, _ in columns)
    lines = [head]
    for r in rows:
        cells = []
        for key, h, fmt in columns:
            v = r.get(key)
            text = "—" if v is None else (format(v, fmt) if fmt else str(v))
            cells.append(f"{text:>{max(len(h), 9)}}")
        lines.append("  ".join(cells))
    return "\n".join(lines)


def write_json(path: Path, payload: dict[str, Any]) -> None:
    payload = {
        **payload,
        "python": sys.version.split()[0],
        "machine": platform.machine(),
        "cpu_count": mp.cpu_count(),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(payload, indent=2, default=float))
    tmp.replace(path)
    print(f"wrote {path}")


def paper_prior_map(sel: Any, truth: Any, scenario: dict[str, Any]) -> Any:
    """The pipeline's GP map (``toolkit.stages.reconstruct_selection``) of a selection, on the
    scenario's site grid, with the paper's 8 x 8 block-averaged prior of ``truth`` and no
    held-out check: the ``terrain.TerrainGP`` product Dataset."""
    from terrain import Grid, TriangulatedMean, coarse_dem
    from toolkit.stages import reconstruct_selection

    grid = Grid.from_bounds(
        tuple(scenario["site"]["bounds"]),
        float(scenario["reconstruct"]["resolution_m"]),
        scenario["site"]["crs"],
    )
    mean = TriangulatedMean(coarse_dem(truth, cells=(8, 8)))
    return reconstruct_selection(sel, grid, mean, scenario, int(scenario["seed"]), 0).product


def real_dems_or_skip(out: Path, name: str) -> bool:
    """True when the real DEMs can be had (``scripts/real_dems.py``); else print why and write
    ``{"benchmark": name, "skipped": why}`` to ``out`` (the benchmark then returns 0)."""
    import real_dems

    try:
        real_dems.fetch()
    except real_dems.RealDataUnavailable as exc:
        print(f"skipped: {exc}")
        write_json(out, {"benchmark": name, "skipped": str(exc)})
        return False
    return True
