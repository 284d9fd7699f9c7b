"""ElevationSamples: the one table the terrain stage reads (docs/architecture.md §3).

Landmarks selected by the factor graph, GPS survey points, LiDAR ground returns or a CSV all
arrive here as x, y, z and an elevation variance (Eq 6's sigma_i^2), validated once.

Duplicate-location policy
-------------------------
Two samples at exactly the same (x, y) are handled by ``duplicates=``:

``"merge"`` (default)
    Samples that agree within their stated noise (``|z_i - z_j| <= 3 sqrt(var_i + var_j)``,
    exact equality when both variances are zero) are merged into one by the inverse-variance
    weighted mean, variance ``1 / sum(1 / var_i)``. The number merged is kept in
    ``n_merged``. Samples that *conflict* raise :class:`DuplicateLocationError`, naming the
    location and values.
``"average"``
    Every group is merged as above even if it conflicts; the merged variance is inflated by
    the group's sample variance so the conflict shows up as uncertainty. Counted in
    ``n_merged``.
``"raise"``
    Any repeated location raises.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from pyproj import CRS

from .errors import DuplicateLocationError, bad_input
from .grid import as_crs

__all__ = ["ElevationSamples"]

DuplicatePolicy = Literal["merge", "average", "raise"]


def _as_finite(name: str, values: Any, ndim: int) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise bad_input(name, values, "numbers", "pass a numeric array") from exc
    if arr.ndim != ndim:
        shape = "(n, 2)" if ndim == 2 else "(n,)"
        raise bad_input(name, arr.shape, f"an array of shape {shape}", "reshape the input")
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = np.argwhere(bad)[0]
        raise bad_input(
            name,
            arr[tuple(idx)],
            f"finite values (first bad entry at index {tuple(idx)})",
            "drop or repair NaN/inf rows before building ElevationSamples",
        )
    return arr


@dataclass(frozen=True)
class ElevationSamples:
    """Point elevations with per-point variance.

    Parameters
    ----------
    xy : ndarray of shape (n, 2)
        Easting, northing in metres, in ``crs``.
    z : ndarray of shape (n,)
        Elevation in metres.
    z_var : ndarray of shape (n,) or float, default 0
        Elevation variance in m^2 (Eq 6, Eq 7), non-negative.
    crs : pyproj.CRS or None
        CRS of ``xy``; checked against grids and priors when given.
    extra : mapping of str to ndarray of shape (n,), optional
        Per-point provenance columns (landmark id, source, first-seen distance...).
    duplicates : {"merge", "average", "raise"}
        Policy for repeated locations (see the module docstring).
    """

    xy: np.ndarray
    z: np.ndarray
    z_var: np.ndarray | float = 0.0
    crs: CRS | None = None
    extra: Mapping[str, np.ndarray] = field(default_factory=dict)
    duplicates: DuplicatePolicy = "merge"
    n_merged: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        xy = _as_finite("xy", self.xy, 2)
        if xy.shape[1] != 2:
            raise bad_input("xy", xy.shape, "shape (n, 2): easting, northing", "pass x, y columns")
        z = _as_finite("z", self.z, 1)
        z_var = _as_finite("z_var", np.broadcast_to(self.z_var, z.shape).copy(), 1)
        n = xy.shape[0]
        if z.shape[0] != n or z_var.shape[0] != n:
            raise bad_input(
                "z / z_var lengths",
                (n, z.shape[0], z_var.shape[0]),
                "xy, z and z_var of the same length n",
                "check that no column was filtered alone",
            )
        if n == 0:
            raise bad_input("xy", xy.shape, "at least one sample", "pass some data")
        if (z_var < 0).any():
            i = int(np.argmin(z_var))
            raise bad_input(
                "z_var",
                z_var[i],
                f"non-negative variances in m^2 (index {i} is negative)",
                "pass variances (sigma**2), not signed errors",
            )
        extra = {k: np.asarray(v) for k, v in dict(self.extra).items()}
        for key, col in extra.items():
            if col.shape[:1] != (n,):
                raise bad_input(f"extra[{key!r}]", col.shape, f"length {n}", "one value per sample")
        if self.duplicates not in ("merge", "average", "raise"):
            raise bad_input(
                "duplicates", self.duplicates, '"merge", "average" or "raise"', "pick one"
            )
        crs = None if self.crs is None else as_crs(self.crs, "samples.crs")
        xy, z, z_var, extra, n_merged = _resolve_duplicates(xy, z, z_var, extra, self.duplicates)
        for name, value in (("xy", xy), ("z", z), ("z_var", z_var)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "extra", extra)
        object.__setattr__(self, "crs", crs)
        object.__setattr__(self, "n_merged", n_merged)

    def __len__(self) -> int:
        return self.z.shape[0]

    @property
    def n(self) -> int:
        """Number of samples (after merging duplicates)."""
        return len(self)

    def subset(self, index: np.ndarray) -> ElevationSamples:
        """The samples selected by an integer or boolean index."""
        return ElevationSamples(
            self.xy[index],
            self.z[index],
            self.z_var[index],
            crs=self.crs,
            extra={k: v[index] for k, v in self.extra.items()},
            duplicates="raise",
        )

    def position_order(self) -> np.ndarray:
        """Indices, shape (n,), that put the samples in order of easting, then northing."""
        return np.lexsort((self.xy[:, 1], self.xy[:, 0]))

    def by_position(self) -> ElevationSamples:
        """The same samples in order of position: easting, then northing (both ascending).

        Every draw a fit makes over the samples (its fit subset, Vecchia orders, evidence
        windows) is made over their indices, so a fit on ``by_position()`` gives the same map,
        to the bit, whatever order the survey's rows came in (docs/terrain.md "The map no
        longer follows the samples' order"). Locations are unique after the duplicate policy,
        so the order is total. Returns ``self`` when the samples are already in that order.
        """
        order = self.position_order()
        if np.array_equal(order, np.arange(self.n)):
            return self
        ordered = self.subset(order)
        object.__setattr__(ordered, "n_merged", self.n_merged)  # merged before the order
        return ordered

    def __repr__(self) -> str:
        crs = self.crs.to_string() if self.crs is not None else None
        return (
            f"ElevationSamples(n={self.n}, z=[{self.z.min():.2f}, {self.z.max():.2f}] m, "
            f"median sigma={np.sqrt(np.median(self.z_var)):.3f} m, crs={crs}, "
            f"n_merged={self.n_merged})"
        )


def _resolve_duplicates(xy, z, z_var, extra, policy):
    """Apply the duplicate-location policy; return the arrays and the number merged away."""
    # Rows as one complex number each: unique sorts them as axis=0 would (real, then
    # imaginary part), 4 x faster on 10 million rows (4.3 against 15.9 s).
    rows = np.ascontiguousarray(xy, dtype=float).view(np.complex128).ravel()
    _, first, inverse, counts = np.unique(
        rows, return_index=True, return_inverse=True, return_counts=True
    )
    inverse = inverse.ravel()
    if counts.max() == 1:
        return xy, z, z_var, extra, 0
    dup_groups = np.flatnonzero(counts > 1)
    if policy == "raise":
        g = dup_groups[0]
        members = np.flatnonzero(inverse == g)
        raise DuplicateLocationError(
            f"xy: {len(dup_groups)} locations are repeated (e.g. rows {members.tolist()} at "
            f"{xy[members[0]].tolist()}). Fix: use duplicates='merge' or remove the repeats."
        )
    # Inverse-variance weights; zero variance members dominate (exact measurements).
    exact = z_var == 0
    group_has_exact = np.bincount(inverse, weights=exact, minlength=counts.size) > 0
    w = np.where(exact, 1.0, 0.0)
    w = np.where(group_has_exact[inverse], w, 1.0 / np.where(exact, 1.0, z_var))
    wsum = np.bincount(inverse, weights=w)
    z_m = np.bincount(inverse, weights=w * z) / wsum
    var_m = np.where(group_has_exact, 0.0, 1.0 / np.where(group_has_exact, 1.0, wsum))
    # Consistency of each member with the merged value.
    resid = np.abs(z - z_m[inverse])
    tol = 3.0 * np.sqrt(z_var + var_m[inverse]) + 1e-9 * (1.0 + np.abs(z))
    conflict = resid > tol
    if policy == "merge" and conflict.any():
        g = inverse[np.flatnonzero(conflict)[0]]
        members = np.flatnonzero(inverse == g)
        raise DuplicateLocationError(
            f"z: samples at the same location {xy[members[0]].tolist()} (rows "
            f"{members.tolist()}) disagree beyond their noise: z={z[members].tolist()}, "
            f"z_var={z_var[members].tolist()}. Fix: repair the data, or pass "
            "duplicates='average' to merge them with the disagreement added to the variance."
        )
    if policy == "average":
        spread = np.bincount(inverse, weights=(z - z_m[inverse]) ** 2) / counts
        var_m = var_m + spread
    order = np.argsort(first)  # keep the original order of first appearance
    keep = first[order]
    new_extra = {k: v[keep] for k, v in extra.items()}
    n_merged = int(xy.shape[0] - counts.size)
    return xy[keep], z_m[order], var_m[order], new_extra, n_merged
