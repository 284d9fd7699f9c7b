"""A coarse DEM read as what it is, a raster of *area means*: the smoothest surface whose
mean over every coarse cell is that cell's value (Tobler 1979, "Smooth pycnophylactic
interpolation for geographical regions", JASA 74:519-530; here with a thin-plate energy).

The paper's satellite prior (Section II-E) places each of its 64 block averages at the
block's centre and joins them by a triangular mesh. A block average is not the elevation at
the centre: on a ridge it is lower, in a valley higher (by about curvature x cell^2 / 24),
and the mesh adds creases along every triangle edge. Here the surface ``u`` lives on a
lattice ``oversample`` times finer than the coarse cells and solves

    minimise   sum (u_xx^2 + 2 u_xy^2 + u_yy^2)       (second differences on the lattice)
    subject to mean of u over coarse cell c = value_c  (one constraint per cell)

by one sparse KKT solve. Between lattice nodes it is bilinear (linear out to the footprint's
edge); beyond the coarse footprint it takes the value at the nearest point of the footprint
(finite and bounded on all of R^2, as :class:`~terrain.prior.TriangulatedMean`).

Measured on eleven real DEMs (docs/terrain.md "The coarse prior read as area means", session
21), the 8 x 8 prior alone over the half of a site without samples: RMSE 2-50 % below the
triangulated mesh on every one of them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import xarray as xr
from scipy.interpolate import RegularGridInterpolator
from scipy.sparse.linalg import spsolve

from .errors import bad_input
from .grid import Grid, north_up
from .linear_mean import OffsetScaleMean, check_xy, parse_offset
from .prior import check_coarse

__all__ = ["PycnophylacticMean"]

#: Largest lattice (nodes) one solve is allowed. Measured on this machine's 2 cores: 6,400
#: nodes (8 x 8 cells at oversample 10) 0.07 s; 62,500 (25 x 25) 1.7 s and 0.5 GB peak;
#: 250,000 (50 x 50) 19 s and 2.2 GB, too slow for a prior.
MAX_LATTICE = 65_000


def _second_difference(n: int) -> sp.csr_matrix:
    """(n - 2, n) operator of ``u[i] - 2 u[i+1] + u[i+2]``."""
    ones = np.ones(n - 2)
    return sp.diags([ones, -2.0 * ones, ones], [0, 1, 2], shape=(n - 2, n), format="csr")


def _first_difference(n: int) -> sp.csr_matrix:
    """(n - 1, n) operator of ``u[i+1] - u[i]``."""
    ones = np.ones(n - 1)
    return sp.diags([-ones, ones], [0, 1], shape=(n - 1, n), format="csr")


def thin_plate_energy(ny: int, nx: int) -> sp.csr_matrix:
    """The (ny nx, ny nx) matrix ``E`` with ``u^T E u = sum u_xx^2 + 2 u_xy^2 + u_yy^2``
    over a row-major lattice (second differences in lattice units; natural boundary)."""
    iy, ix = sp.identity(ny, format="csr"), sp.identity(nx, format="csr")
    dxx = sp.kron(iy, _second_difference(nx))
    dyy = sp.kron(_second_difference(ny), ix)
    dxy = sp.kron(_first_difference(ny), _first_difference(nx))
    return (dxx.T @ dxx + dyy.T @ dyy + 2.0 * dxy.T @ dxy).tocsr()


def block_means(ny: int, nx: int, f: int) -> sp.csr_matrix:
    """The (ny nx, ny f nx f) matrix taking a row-major lattice ``f`` times finer than a
    (ny, nx) grid to the mean over each coarse cell."""
    cell = (np.arange(ny * f)[:, None] // f) * nx + (np.arange(nx * f)[None, :] // f)
    n = ny * f * nx * f
    return sp.csr_matrix((np.full(n, 1.0 / f**2), (cell.ravel(), np.arange(n))), shape=(ny * nx, n))


def area_preserving_surface(values: np.ndarray, f: int) -> np.ndarray:
    """The smoothest lattice ``(ny f, nx f)`` whose block means are ``values`` (ny, nx).

    Solves the KKT system ``[[E, A^T], [A, 0]] [u; lambda] = [0; values]`` (E:
    :func:`thin_plate_energy`, A: :func:`block_means`). Needs at least 2 x 2 cells: a plane
    across one row of cells keeps every block mean, so the surface would not be unique.
    """
    ny, nx = values.shape
    E = thin_plate_energy(ny * f, nx * f)
    A = block_means(ny, nx, f)
    kkt = sp.bmat([[E, A.T], [A, None]], format="csc")
    rhs = np.concatenate([np.zeros(E.shape[0]), values.ravel()])
    return spsolve(kkt, rhs)[: E.shape[0]].reshape(ny * f, nx * f)


class PycnophylacticMean(OffsetScaleMean):
    """A coarse DEM of area means as the smoothest surface that keeps each cell's mean.

    Parameters
    ----------
    coarse : xarray.DataArray
        Coarse DEM (dims y, x, y ascending or descending; metres; e.g. from
        :func:`~terrain.prior.coarse_dem`), each value the *mean* over its cell; all
        finite; at least 2 x 2 cells.
    oversample : int
        Lattice nodes per coarse cell along each axis (>= 2; default 10). The lattice may
        hold at most :data:`MAX_LATTICE` nodes.
    offset : {"none", "fit"} or float
        As :class:`~terrain.prior.TriangulatedMean`: the surface as is, ``a + b * surface``
        estimated by the GP, or the surface plus a number of metres.

    Attributes
    ----------
    crs : pyproj.CRS
        CRS of the coarse grid; query points must be in it.
    lattice : ndarray, shape (ny * oversample, nx * oversample)
        The surface at the lattice nodes, north row first, metres.
    """

    def __init__(self, coarse: xr.DataArray, oversample: int = 10, offset: str | float = "none"):
        self.offset = parse_offset(offset)
        check_coarse(coarse)
        if isinstance(oversample, bool) or not isinstance(oversample, int | np.integer):
            raise bad_input("oversample", oversample, "an integer >= 2", "oversample=10")
        if oversample < 2:
            raise bad_input("oversample", oversample, "an integer >= 2", "oversample=10")
        self.grid = Grid.from_dataarray(coarse)
        self.crs = self.grid.crs
        values = np.asarray(north_up(coarse).values, dtype=float)
        if min(values.shape) < 2:
            raise bad_input(
                "coarse",
                f"{values.shape[0]} x {values.shape[1]} cells",
                "at least 2 x 2 cells (a plane along one row keeps every cell's mean)",
                "use TriangulatedMean for a single row or column of cells",
            )
        if not np.all(np.isfinite(values)):
            raise bad_input(
                "coarse",
                f"{int((~np.isfinite(values)).sum())} NaN cells",
                "finite values on its grid",
                "fill or drop the NaN cells first",
            )
        nodes = values.size * oversample**2
        if nodes > MAX_LATTICE:
            raise bad_input(
                "oversample",
                f"{oversample} ({nodes:,} lattice nodes for {values.shape[0]} x "
                f"{values.shape[1]} cells)",
                f"at most {MAX_LATTICE:,} nodes",
                "pass a smaller oversample; a DEM with this many cells is fine enough for "
                "RasterMean",
            )
        self.oversample = int(oversample)
        self.values = values
        self.lattice = area_preserving_surface(values, self.oversample)
        w, s, e, n = self.grid.bounds
        my, mx = self.lattice.shape
        ys = s + (np.arange(my) + 0.5) * (n - s) / my  # south first for the interpolator
        xs = w + (np.arange(mx) + 0.5) * (e - w) / mx
        # Linear within the footprint's outer half node (the slope kept to its edge), the
        # edge's value beyond it.
        self._lo, self._hi = np.array([w, s]), np.array([e, n])
        self._interp: Callable = RegularGridInterpolator(
            (ys, xs), self.lattice[::-1], bounds_error=False, fill_value=None
        )

    def dem(self, xy: np.ndarray) -> np.ndarray:
        """The surface itself (m) at ``xy`` (n, 2) -> (n,), before any offset: bilinear
        between lattice nodes (linear out to the footprint's edge), the nearest footprint
        point's value beyond it."""
        q = np.clip(check_xy(xy), self._lo, self._hi)
        return self._interp(q[:, ::-1])

    def __repr__(self) -> str:
        w, s, e, n = self.grid.bounds
        return (
            f"PycnophylacticMean(cells={self.grid.shape}, oversample={self.oversample}, "
            f"bounds=({w:.1f}, {s:.1f}, {e:.1f}, {n:.1f}), crs={self.crs.to_string()}"
            + ("" if self.offset == "none" else f", {self._coef_text()}")
            + ")"
        )
