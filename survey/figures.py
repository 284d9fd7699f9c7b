"""Figures of a Monte Carlo sweep in the style of the paper's Fig. 10 and 11."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from terrain.atomic import atomic_path

__all__ = ["plot_plan", "plot_sweep"]

_LABELS = {"lawnmower": "Lawnmower", "piecewise_continuous": "Piecewise continuous"}


def plot_sweep(summary: dict[str, Any], out_dir: str | Path) -> list[Path]:
    """Write ``fig10_rmse_vs_swaths.png`` (mean ± std RMSE per pattern with every limit
    drawn, Fig. 10) and ``fig11_class_limit.png`` (mean RMSE against the first limit, with
    the minimum swath counts marked, Fig. 11). Returns the paths written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    table = summary["by_pattern"]
    limits = summary["limits_m"]
    paths = []
    fig, ax = plt.subplots(figsize=(7, 4.5), constrained_layout=True)
    for pattern, rows in table.items():
        n = sorted(int(k) for k in rows)
        mean = [rows[str(k)]["rmse_mean"] for k in n]
        std = [rows[str(k)]["rmse_std"] for k in n]
        ax.errorbar(n, mean, yerr=std, marker="o", capsize=3, label=_LABELS.get(pattern, pattern))
    for i, (label, limit) in enumerate(limits.items()):
        ax.axhline(limit, ls="--", color=f"C{i + 2}", lw=1, label=f"{label}: {limit:.4g} m")
    ax.set(
        xlabel="number of swaths",
        ylabel="RMSE [m]",
        yscale="log",
        title=f"Reconstruction error over {_n_terrains(table)} random terrains",
    )
    ax.legend(fontsize=8)
    paths.append(_save(fig, out_dir / "fig10_rmse_vs_swaths.png"))
    plt.close(fig)

    label, limit = next(iter(limits.items()))
    fig, ax = plt.subplots(figsize=(7, 4.5), constrained_layout=True)
    for pattern, rows in table.items():
        n = sorted(int(k) for k in rows)
        ax.plot(
            n,
            [rows[str(k)]["rmse_mean"] for k in n],
            marker="o",
            label=_LABELS.get(pattern, pattern),
        )
        best = summary["minimum_swaths"][label].get(pattern)
        if best is not None:
            ax.plot([best], [rows[str(best)]["rmse_mean"]], "k*", ms=14)
    ax.axhline(limit, color="r", lw=1.5, label=f"{label} ({limit:.4g} m)")
    ax.set(
        xlabel="number of swaths",
        ylabel="mean RMSE [m]",
        yscale="log",
        title="Minimum swaths meeting the class (stars)",
    )
    ax.legend(fontsize=8)
    paths.append(_save(fig, out_dir / "fig11_class_limit.png"))
    plt.close(fig)
    return paths


def _n_terrains(table: dict[str, Any]) -> int:
    return max(int(e["n_terrains"]) for rows in table.values() for e in rows.values())


def _save(fig, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    return path


def plot_plan(plan, prior, path: str | Path) -> Path:
    """The plan's driven path and samples over the prior DEM, as a PNG (paper Fig. 7, 12)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(7, 6), constrained_layout=True)
    x, y = np.asarray(prior["x"]), np.asarray(prior["y"])
    im = ax.imshow(
        np.asarray(prior.values), extent=(x[0], x[-1], y[-1], y[0]), origin="upper", cmap="terrain"
    )
    fig.colorbar(im, ax=ax, shrink=0.8, label="prior elevation [m]")
    wp = plan.waypoints
    ax.plot(wp[:, 0], wp[:, 1], "k-", lw=1.0, label="driven path")
    ax.plot(plan.samples[:, 0], plan.samples[:, 1], ".", ms=2, color="crimson", label="samples")
    ax.set(
        xlabel="easting [m]",
        ylabel="northing [m]",
        aspect="equal",
        title=f"{_LABELS.get(plan.pattern, plan.pattern)}, {plan.n_swaths} swaths, "
        f"{plan.path_length:.0f} m",
    )
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.legend(loc="lower right", fontsize=8)
    path = Path(path)
    _save(fig, path)
    plt.close(fig)
    return path
