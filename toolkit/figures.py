"""Figures for reports and the demo (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_path

__all__ = ["plot_demo"]


def plot_demo(result, path: str | Path) -> Path:
    """Truth, the three reconstructions and the GP's 1-sigma, as one PNG (paper Fig. 5-6)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    truth = result.truth
    w, e = float(truth.x.min()), float(truth.x.max())
    s, n = float(truth.y.min()), float(truth.y.max())
    extent = (0, e - w, 0, n - s)  # local metres from the south-west corner
    vmin, vmax = float(truth.min()), float(truth.max())
    panels = [
        ("Ground truth", truth.values, "terrain", (vmin, vmax)),
        (
            "GP + satellite prior",
            result.maps["gp_satellite"]["elevation"].values,
            "terrain",
            (vmin, vmax),
        ),
        (
            "GP, constant mean",
            result.maps["gp_constant"]["elevation"].values,
            "terrain",
            (vmin, vmax),
        ),
        ("Delaunay linear", result.maps["delaunay"]["elevation"].values, "terrain", (vmin, vmax)),
        (
            "GP + satellite 1-sigma",
            result.maps["gp_satellite"]["elevation_std"].values,
            "magma",
            (0.0, None),
        ),
        (
            "GP + satellite |error|",
            np.abs(result.maps["gp_satellite"]["elevation"].values - truth.values),
            "viridis",
            (0.0, None),
        ),
    ]
    fig, axes = plt.subplots(2, 3, figsize=(15, 9.5), constrained_layout=True)
    px, py = result.path[:, 0] - w, result.path[:, 1] - s
    for ax, (title, img, cmap, (lo, hi)) in zip(axes.ravel(), panels, strict=True):
        im = ax.imshow(img, extent=extent, origin="upper", cmap=cmap, vmin=lo, vmax=hi)
        ax.plot(px, py, color="k", lw=0.8)
        key = {
            "GP + satellite prior": "gp_satellite",
            "GP, constant mean": "gp_constant",
            "Delaunay linear": "delaunay",
        }.get(title)
        if key:
            m = result.metrics[key]
            title += f"\nRMSE {m['rmse']:.3f} m, covers {100 * m['covered_fraction']:.1f} %"
        ax.set_title(title)
        ax.set_xlabel("easting from SW corner [m]")
        ax.set_ylabel("northing [m]")
        fig.colorbar(im, ax=ax, shrink=0.8, label="m")
    fig.suptitle(f"glacimap reconstruct --demo  (seed {result.seed}, {result.samples.n} landmarks)")
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=80, format="png")
    plt.close(fig)
    return path
