"""The start of a :class:`terrain.BreaklineMean`'s steps: the samples beside each line, each
stretch of ``2 R`` along it with a plane of its own, and the steps' heights by least squares
on them (a global start would read the two halves' trend difference as step height)."""

from __future__ import annotations

from typing import Any

import numpy as np

from .breakline_geometry import plane_columns
from .errors import bad_input
from .linear_mean import ols_coefficients

__all__ = ["local_fit", "near_samples"]


def near_samples(mean: Any, xy: np.ndarray, reach: float) -> dict[str, Any]:
    """The samples within ``reach`` (m) of ``mean``'s lines (their geometry, as the mean's
    columns take it) and the planes of their stretches."""
    geom = mean._geometry(xy, reach)
    D = geom["D"]
    planes, rows = [], np.zeros(len(xy), dtype=bool)  # (samples, their plane's columns)
    for j in range(len(mean.lines)):
        near = np.abs(D[:, j]) <= reach
        idx = np.flatnonzero(near)
        stretch = np.floor(mean._arcs(geom, j, idx) / (2.0 * reach))
        both = 0
        for k in np.unique(stretch):
            m = idx[stretch == k]
            plane = plane_columns(xy[m])
            if plane is None:
                near[m] = False  # too few samples for a plane of their own: not used
                continue
            both += int(np.any(D[m, j] > 0) and np.any(D[m, j] < 0))
            planes.append((m, plane))
        if both == 0:
            raise bad_input(
                f"lines[{j}]",
                "no samples on both sides",
                f"samples within {reach:.0f} m of the line on either side of it",
                "survey across the breakline, or leave it out",
            )
        rows |= near
    kept = {
        "xy": xy[rows],
        "D": D[rows],
        "s": [s[rows] for s in geom["s"]],
        "layers": {},
    }
    return {"geom": kept, "planes": planes, "rows": rows}


def local_fit(mean: Any, z, widths, tapers, near) -> tuple[np.ndarray, np.ndarray, float]:
    """(steps, their covariance, residual sum of squares): least squares of ``z`` on the
    planes and the step columns of ``mean`` at ``widths`` and ``tapers``, on the samples of
    :func:`near_samples` (``BreaklineMean.local_steps``)."""
    rows, planes = near["rows"], near["planes"]
    where = np.full(rows.size, -1)
    where[rows] = np.arange(int(rows.sum()))
    cols = np.cumsum([0] + [plane.shape[1] for _, plane in planes])
    H = np.zeros((int(rows.sum()), cols[-1] + len(mean.lines)))
    for k, (idx, plane) in enumerate(planes):
        H[where[idx], cols[k] : cols[k + 1]] = plane
    H[:, cols[-1] :] = mean._columns(near["geom"], widths, tapers)[0]
    beta, cov = ols_coefficients(H, z[rows])
    rss = float(np.sum((z[rows] - H @ beta) ** 2))
    n = len(mean.lines)
    return beta[-n:], cov[-n:, -n:], rss
