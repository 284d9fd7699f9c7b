"""Where the default map stands: issue 16's counts over ``real_terrain.py`` result files.

    python benchmarks/standing.py                       # the current result files (STANDING)
    python benchmarks/standing.py FILE.json ... --by-family --out standing.json

Reads the ``verdicts`` each ``benchmarks/real_terrain.py`` run writes and counts, per file
and sample count, the glacimap rows (both means) that meet each of issue 16's targets:

``accuracy``  RMSE <= 0.8 x Delaunay's on its hull *and* <= the thin-plate RBF's;
``truth``     the truth's coverage in 92-98 % at 95 and 62-76 % at 68;
``held-out``  ``cross_validate``'s map coverage within 3 points of the truth's at both.

Each miss is listed as ``site/mean`` with the number that missed. ``--by-family`` adds the
mean 68 % coverage of the rows by the kernel family the evidence chose (Microscale parts
left out), at 3,000-10,000 and at 20,000 samples or more. Nothing is recomputed: the
numbers are those of the files.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _harness import table, write_json  # noqa: E402

RESULTS = HERE / "results"
#: The files that hold the standing: every row at the samples'-position draw (session 46:
#: the fits draw over the samples in order of position, a new draw of every map; docs/
#: terrain.md "The map no longer follows the samples' order"): 0.45.0's re-runs (session
#: 46) and, for the files still at 0.32.0-0.34.0's draw then, session 48's (0.46.0's map,
#: the same as 0.45.0's): window 0, the ten windows, a third window of each DEM, bilinear
#: facets, 80-node windows, and a survey that kept to its tracks (2 % scattered).
STANDING = (
    "real_terrain_s46_3k.json",
    "real_terrain_s48_5k.json",
    "real_terrain_s48_10k.json",
    "real_terrain_s48_20k.json",
    "real_terrain_spread_windows_s46_50k.json",
    "real_terrain_tenwin_s46_3k.json",
    "real_terrain_tenwin_s48_10k.json",
    "real_terrain_tenwin_s48_50k.json",
    "real_terrain_newwin_s46_3k.json",
    "real_terrain_newwin_s46_50k.json",
    "real_terrain_linear_s46_3k.json",
    "real_terrain_linear_s48_50k.json",
    "real_terrain_nodes80_s46_3k.json",
    "real_terrain_nodes80_s46_50k.json",
    "real_terrain_scattered2_s46_3k.json",
    "real_terrain_scattered2_s46_50k.json",
)
#: The prior mean of each glacimap method, as the misses name it.
MEANS = {
    "glacimap": "const",
    "glacimap_dem": "8x8",
    "glacimap_pycno": "area-means",
    "glacimap_breakline": "breakline",
    "glacimap_breakline_across": "breakline-across",
    "glacimap_breakline_found": "breakline-found",
    "glacimap_breakline_dem": "breakline-8x8",
}
#: Which verdict keys make each target (all must pass).
TARGETS = {
    "accuracy": (("rmse_ok", "rmse_over_delaunay"), ("rbf_ok", "rmse_over_rbf")),
    "truth": (("cov95_ok", "cov95"), ("cov68_ok", "cov68")),
    "held-out": (("cv_ok", "d68"),),
}


def _passed(value: Any) -> bool:
    return value is True or value == "PASS"


def load(spec: str | Path) -> dict[str, Any]:
    """A result file's verdicts and the kernel family of each glacimap row; ``FILE:N`` keeps the
    rows of ``N`` samples only."""
    path, only = str(spec), None
    head, sep, tail = path.rpartition(":")
    if sep and tail.isdigit():
        path, only = head, int(tail)
    if not Path(path).is_file():
        raise SystemExit(f"{path}: no such result file; run benchmarks/real_terrain.py --out it")
    data = json.loads(Path(path).read_text())
    if "verdicts" not in data:
        raise SystemExit(f"{path}: no verdicts (a run still going, or not real_terrain.py's)")
    # the family the search kept, as it named it (kernel_search.FAMILY; Microscale aside)
    kernels = {
        (r["site"], r["n"], r["method"]): next(
            (c["name"] for c in r.get("info", {}).get("kernel_scores") or [] if c["selected"]),
            "not recorded",
        )
        for r in data["results"]
    }
    rows = []
    for v in data["verdicts"]:
        if v["method"].startswith("glacimap") and (only is None or int(v["n"]) == only):
            family = kernels.get((v["site"], v["n"], v["method"]), "not recorded")
            rows.append({**v, "family": family})
    return {"file": Path(path).name, "rows": rows}


def _miss(row: dict[str, Any], target: str) -> str | None:
    keys = TARGETS[target]
    if all(_passed(row.get(ok)) for ok, _ in keys):
        return None
    if target == "held-out":  # both levels, signed: the check minus the truth
        shown = f"{row['d95']:+.1f} / {row['d68']:+.1f}"
    else:  # the values that missed: ratios to 3 decimals, coverages to 1
        shown = ", ".join(
            f"{row[val]:.3f}" if val.startswith("rmse") else f"{row[val]:.1f}"
            for ok, val in keys
            if not _passed(row.get(ok)) and row.get(val) is not None
        )
    mean = MEANS.get(row["method"], row["method"])
    return f"{row['site']}/{mean} {shown}"


def counts(result: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per sample count of a file: rows and each target's passes and misses."""
    by_n: dict[int, list] = defaultdict(list)
    for row in result["rows"]:
        by_n[int(row["n"])].append(row)
    out = []
    for n, rows in sorted(by_n.items()):
        name = result["file"].removeprefix("real_terrain_").removesuffix(".json")
        line: dict[str, Any] = {"file": name, "n": n, "rows": len(rows)}
        for target in TARGETS:
            misses = [m for m in (_miss(r, target) for r in rows) if m is not None]
            line[target] = len(rows) - len(misses)
            line[f"{target} misses"] = misses
        out.append(line)
    return out


def by_family(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Mean 68 % / 95 % truth coverage by chosen family, below and from 20,000 samples."""
    groups: dict[tuple[str, str], list] = defaultdict(list)
    for result in results:
        for row in result["rows"]:
            size = ">=20k" if row["n"] >= 20_000 else "<20k"
            groups[(row["family"], size)].append(row)
    out = []
    for (family, size), rows in sorted(groups.items()):
        out.append(
            {
                "family": family,
                "samples": size,
                "rows": len(rows),
                "mean cov68": sum(r["cov68"] for r in rows) / len(rows),
                "mean cov95": sum(r["cov95"] for r in rows) / len(rows),
                "wide": sum(r["cov68"] > 76 or r["cov95"] > 98 for r in rows),
                "narrow": sum(r["cov68"] < 62 or r["cov95"] < 92 for r in rows),
            }
        )
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("files", nargs="*", help="result files, FILE:N for one sample count")
    p.add_argument("--by-family", action="store_true", help="coverage by the chosen family")
    p.add_argument("--out", type=Path, default=None, help="also write the counts as JSON")
    args = p.parse_args(argv)
    files = args.files or [str(RESULTS / f) for f in STANDING]
    results = [load(f) for f in files]
    lines = [line for r in results for line in counts(r)]
    total = {"file": "all", "n": None, "rows": sum(line["rows"] for line in lines)}
    total.update({t: sum(line[t] for line in lines) for t in TARGETS})
    width = max(len(line["file"]) for line in lines)
    columns = [("file", "file".rjust(width), ""), ("n", "n", "d"), ("rows", "rows", "d")]
    columns += [(t, t, "d") for t in TARGETS]
    print(table([*lines, total], columns))
    for line in lines:
        for target in TARGETS:
            if line[f"{target} misses"]:
                misses = "; ".join(line[f"{target} misses"])
                print(f"  {line['file']} n={line['n']} {target} misses: {misses}")
    payload: dict[str, Any] = {"benchmark": "standing", "files": [str(f) for f in files]}
    payload["counts"] = lines
    payload["total"] = total
    if args.by_family:
        fam = by_family(results)
        print()
        print(
            table(
                fam,
                [
                    ("family", "family", ""),
                    ("samples", "samples", ""),
                    ("rows", "rows", "d"),
                    ("mean cov68", "mean cov68", ".1f"),
                    ("mean cov95", "mean cov95", ".1f"),
                    ("wide", "wide", "d"),
                    ("narrow", "narrow", "d"),
                ],
            )
        )
        payload["by_family"] = fam
    if args.out is not None:
        write_json(args.out, payload)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
