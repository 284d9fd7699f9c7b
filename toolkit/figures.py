"""Figures for reports and the demo (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from terrain.atomic import atomic_path
from terrain.metrics import calibration_curve

__all__ = ["plot_demo", "plot_hillshade"]


def plot_demo(result, path: str | Path) -> Path:
    """Truth, the three reconstructions, 1-sigma, error, calibration and samples as one PNG
    (paper Fig. 5-6)."""
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
    fig, axes = plt.subplots(2, 4, figsize=(20, 9.5), constrained_layout=True)
    px, py = result.path[:, 0] - w, result.path[:, 1] - s
    for ax, (title, img, cmap, (lo, hi)) in zip(axes.ravel()[:6], panels, strict=True):
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
    ax = axes.ravel()[6]
    for key, label in (("gp_satellite", "GP + satellite prior"), ("gp_constant", "GP, constant")):
        ds = result.maps[key]
        levels, observed = calibration_curve(ds["elevation"], ds["elevation_std"], truth)
        ax.plot(levels, observed, "o-", label=label)
    ax.plot([0, 1], [0, 1], "k--", lw=0.8, label="calibrated")
    ax.set(
        xlabel="nominal interval level",
        ylabel="fraction of cells inside",
        title="Calibration of the 1-sigma maps",
        xlim=(0, 1),
        ylim=(0, 1),
    )
    ax.legend(loc="upper left")
    ax = axes.ravel()[7]
    xy = result.samples.xy
    sc = ax.scatter(xy[:, 0] - w, xy[:, 1] - s, c=np.sqrt(result.samples.z_var), s=1, cmap="plasma")
    ax.set(
        xlim=extent[:2],
        ylim=extent[2:],
        aspect="equal",
        title=f"{result.samples.n} landmarks (colour: 1-sigma)",
        xlabel="easting from SW corner [m]",
        ylabel="northing [m]",
    )
    fig.colorbar(sc, ax=ax, shrink=0.8, label="m")
    fig.suptitle(f"glacimap reconstruct --demo  (seed {result.seed}, {result.samples.n} landmarks)")
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=80, format="png")
    plt.close(fig)
    return path


def plot_hillshade(ds, path: str | Path, title: str = "") -> Path:
    """Hillshade of ``elevation`` beside a hillshade of ``elevation_std``: seams between
    tiles or blocks would show up as straight lines in either (matplotlib LightSource)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LightSource

    dx = float(abs(ds.x[1] - ds.x[0]))
    ls = LightSource(azdeg=315, altdeg=35)
    fig, axes = plt.subplots(1, 2, figsize=(13, 6.2), constrained_layout=True)
    for ax, var, label in zip(
        axes, ("elevation", "elevation_std"), ("mean elevation", "1-sigma"), strict=True
    ):
        z = np.asarray(ds[var].values, dtype=float)
        exag = 1.0 if var == "elevation" else 50.0  # the std surface is flat: exaggerate
        ax.imshow(
            ls.hillshade(z, vert_exag=exag, dx=dx, dy=dx),
            cmap="gray",
            extent=(0, z.shape[1] * dx, 0, z.shape[0] * dx),
        )
        ax.set(title=f"hillshade of the {label}", xlabel="m", ylabel="m")
    fig.suptitle(title)
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=80, format="png")
    plt.close(fig)
    return path
