"""Satellite priors and GP mean functions (paper, Section II-C).

The paper's GP uses either a constant mean ("the mean of all the observation values") or a
mean interpolated from coarse satellite data: "the raw DEM contained only 64 values", turned
into "a triangular mesh terrain model capable of interpolating the elevation at any point"
(Section II-E). :func:`coarse_dem` makes such a DEM from a synthetic truth (block averages,
as a satellite "average[s] the terrain elevation over a large area"); :class:`TriangulatedMean`
interpolates it linearly on the Delaunay triangulation and, unlike a bare mesh, is defined on
all of R^2 (the GP's mean must be evaluable at every query point).

A mean function is any callable ``xy (n, 2) -> (n,)`` in metres; the GP calls
``mean.fit(xy, z)`` first when the object has a ``fit`` method.

Linear-mean protocol (R&W Section 2.7, explicit basis functions). A mean whose ``n_coef`` is
> 0 is ``m(x) = h(x)^T beta``: ``basis(xy)`` gives ``H`` (n, n_coef), ``coef_names`` names the
columns, ``with_coefficients(beta, cov)`` returns a copy evaluating ``H @ beta`` (the GP
estimates ``beta`` by generalised least squares), and ``fit(xy, z)`` is the ordinary least
squares fallback. ``n_coef == 0`` is a fixed mean: evaluate it, do not ask for a basis.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from numbers import Real
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import Delaunay

from .errors import NotFittedError, bad_input
from .grid import Grid, north_up
from .linear_mean import (
    OffsetScaleMean,
    check_coefficients,
    check_xy,
    check_z,
    format_coefficients,
    parse_offset,
)

__all__ = ["ConstantMean", "TriangulatedMean", "as_mean_function", "coarse_dem"]

MeanFunction = Callable[[np.ndarray], np.ndarray]
_CHUNK = 65536  # query points per chunk when projecting onto the hull edges


def coarse_dem(
    truth: xr.DataArray,
    cells: tuple[int, int] = (8, 8),
    noise: float = 0.0,
    seed: int | np.random.Generator | None = None,
) -> xr.DataArray:
    """Block-average ``truth`` into ``cells`` coarse cells: a satellite-like DEM.

    With the default 8 x 8 cells this is the paper's "raw DEM [that] contained only 64
    values" (Section II-E).

    Parameters
    ----------
    truth : xarray.DataArray
        Fine elevation raster (dims y, x; metres) made by :meth:`Grid.data_array`.
    cells : tuple of int
        ``(ny, nx)`` coarse cells over the same bounds (``Grid.coarsen``).
    noise : float
        Standard deviation (m) of Gaussian noise added to each coarse value.
    seed : int, Generator or None
        Seed of the noise (``np.random.default_rng``).

    Returns
    -------
    xarray.DataArray
        Shape ``cells``; each value is the mean of the finite fine cells whose *centre* lies
        in that coarse cell (cells are half-open: a centre exactly on an edge goes to the
        cell east / south of it), so shapes need not divide evenly.
    """
    fine = Grid.from_dataarray(truth)
    truth = north_up(truth)  # rows north first, as the grid's cell centres
    coarse = fine.coarsen(cells)
    if not (np.isfinite(noise) and noise >= 0):
        raise bad_input("noise", noise, "a standard deviation >= 0 in metres", "e.g. 0.5")
    (fy, fx), (cy, cx) = fine.shape, coarse.shape
    # Exact integer arithmetic: centre (i + 1/2) fine cells -> floor((2i + 1) c / 2f).
    col = (2 * np.arange(fx) + 1) * cx // (2 * fx)
    row = (2 * np.arange(fy) + 1) * cy // (2 * fy)
    idx = (row[:, None] * cx + col[None, :]).ravel()
    vals = np.asarray(truth.values, dtype=float).ravel()
    ok = np.isfinite(vals)
    count = np.bincount(idx[ok], minlength=cy * cx)
    total = np.bincount(idx[ok], weights=vals[ok], minlength=cy * cx)
    if (count == 0).any():
        r, c = divmod(int(np.flatnonzero(count == 0)[0]), cx)
        where = f"coarse cell (row {r}, col {c}) centred at ({coarse.x[c]:.1f}, {coarse.y[r]:.1f})"
        fix = "use fewer cells, or fill the NaN area of the truth"
        raise bad_input("truth", where, "at least one finite fine cell per coarse cell", fix)
    values = (total / count).reshape(cy, cx)
    if noise > 0:
        values = values + np.random.default_rng(seed).normal(0.0, noise, values.shape)
    seed_attr = seed if isinstance(seed, int | np.integer) else str(seed)
    return coarse.data_array(
        values,
        truth.name or "elevation",
        units=truth.attrs.get("units", "m"),
        cells=(cy, cx),
        noise=float(noise),
        seed=seed_attr,
        source="block average",
    )


@dataclass(frozen=True)
class ConstantMean:
    """A constant mean function, metres.

    Parameters
    ----------
    value : float, optional
        The constant; ``None`` means "the mean of the observations" (the paper's default,
        Section II-C), set by :meth:`fit`.

    Notes
    -----
    With ``value=None`` this is a linear mean (:mod:`terrain.linear_mean`) with one
    coefficient: ``basis`` is a column of ones, ``coef_names == ("mean_m",)``, so a GP may
    estimate the constant by generalised least squares; with a given value ``n_coef == 0``.
    """

    value: float | None = None
    value_: float | None = None
    coef_cov_: np.ndarray | None = field(default=None, repr=False, compare=False)

    coef_names = ("mean_m",)

    def __post_init__(self) -> None:
        for name in ("value", "value_"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, Real) and np.isfinite(v)):
                raise bad_input(f"mean.{name}", v, "a finite number of metres or None", "e.g. 0")
        if self.value is not None and self.value_ is None:
            object.__setattr__(self, "value_", float(self.value))

    @property
    def n_coef(self) -> int:
        """1 when the constant is estimated (``value=None``), 0 when it is given."""
        return 1 if self.value is None else 0

    @property
    def coef_(self) -> np.ndarray | None:
        """``[value_]`` once estimated (``value=None``), else ``None``."""
        return None if self.value is not None or self.value_ is None else np.array([self.value_])

    def basis(self, xy: np.ndarray) -> np.ndarray:
        """A column of ones, shape (n, 1) (only for ``value=None``)."""
        if self.n_coef == 0:
            raise bad_input(
                "mean.value",
                self.value,
                "None for a mean with a linear coefficient (n_coef > 0)",
                "check mean.n_coef first; a fixed mean is evaluated as mean(xy)",
            )
        return np.ones((len(check_xy(xy)), 1))

    def with_coefficients(self, beta: Any, cov: Any) -> ConstantMean:
        """A copy with ``value_ = beta[0]`` (m) and ``coef_cov_ = cov`` (1, 1), m^2."""
        beta, cov = check_coefficients(self, beta, cov)
        return replace(self, value_=float(beta[0]), coef_cov_=cov)

    def fit(self, xy: np.ndarray, z: np.ndarray) -> ConstantMean:
        """A fitted copy: ``value_`` = ``value`` if given, else the mean of ``z`` (n,) (the
        least-squares constant, with ``coef_cov_ = var(z) / n``, NaN for one sample)."""
        xy, z = check_z(xy, z)
        if self.value is not None:
            return replace(self, value_=float(self.value))
        var = float(z.var(ddof=1)) / z.size if z.size > 1 else np.nan
        return replace(self, value_=float(z.mean()), coef_cov_=np.array([[var]]))

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """The constant at each of ``xy`` (n, 2) -> (n,)."""
        if self.value_ is None:
            raise NotFittedError(
                "ConstantMean() (mean of the observations) was called before fit. Fix: call "
                "mean.fit(xy, z) first, or give a value: ConstantMean(100.0)."
            )
        return np.full(len(check_xy(xy)), self.value_)

    def __repr__(self) -> str:
        text = f"ConstantMean(value={self.value!r}, value_={self.value_!r}"
        if self.coef_cov_ is not None and self.coef_ is not None:
            text += ", " + format_coefficients(self.coef_names, self.coef_, self.coef_cov_)
        return text + ")"


def check_coarse(coarse: Any) -> None:
    """A coarse DEM must be an ``xarray.DataArray`` (an ``InputError`` naming ``coarse``)."""
    if not isinstance(coarse, xr.DataArray):
        raise bad_input(
            "coarse",
            type(coarse).__name__,
            "an xarray.DataArray DEM",
            "make one with coarse_dem(truth) or Grid.data_array",
        )


class TriangulatedMean(OffsetScaleMean):
    """Linear interpolation of a coarse DEM on the Delaunay triangulation of its cell centres.

    Inside the convex hull of the centres this is the paper's triangular mesh of satellite
    values (Section II-E). With ``extrapolate="linear"`` (default) the lattice is first
    padded by one ring of linearly extrapolated cells, so the mesh covers the DEM's whole
    footprint and the outer half cell keeps the slope; ``"nearest"`` skips the ring. Beyond
    the mesh it takes the value at the nearest point of its boundary (linear along that
    edge), so it is defined, finite and bounded on all of R^2 and continuous everywhere.

    Parameters
    ----------
    coarse : xarray.DataArray
        Coarse DEM (dims y, x, y ascending or descending; metres; e.g. from
        :func:`coarse_dem`); all values finite.
    extrapolate : {"linear", "nearest"}
        Whether one ring of linearly extrapolated cells pads the lattice (see above).
    offset : {"none", "fit"} or float
        ``"none"`` (default): the mesh as is. ``"fit"``: ``a + b * mesh(x)``, a linear mean
        (:mod:`terrain.linear_mean`) with basis ``[1, mesh(xy)]`` and ``coef_names``
        ``("offset_m", "scale")``, estimated by the GP (or :meth:`fit`, least squares).
        A number: the mesh plus that many metres.

    Attributes
    ----------
    crs : pyproj.CRS
        CRS of the coarse grid; query points must be in it.
    points : ndarray, shape (m, 2)
        Cell centres (easting, northing), metres.
    values : ndarray, shape (m,)
        Elevations at the centres, metres.
    """

    def __init__(
        self, coarse: xr.DataArray, extrapolate: str = "linear", offset: str | float = "none"
    ) -> None:
        self.offset = parse_offset(offset)
        if extrapolate not in ("linear", "nearest"):
            raise bad_input(
                "extrapolate",
                extrapolate,
                '"linear" or "nearest"',
                '"linear" continues the slope over one extra ring of cells',
            )
        self.extrapolate = extrapolate
        check_coarse(coarse)
        self.grid = Grid.from_dataarray(coarse)
        coarse = north_up(coarse)  # values row-major from the north, as grid.xy()
        self.crs = self.grid.crs
        self.points = self.grid.xy()
        self.values = np.asarray(coarse.values, dtype=float).ravel()
        if self.values.size != len(self.points) or not np.all(np.isfinite(self.values)):
            raise bad_input(
                "coarse",
                "NaN or misshapen values",
                "finite values on its grid",
                "fill or drop the NaN cells first",
            )
        self._interp = self._edges = None
        if min(self.grid.shape) > 1:  # a 2-D lattice: triangulate
            points, values = self.points, self.values
            if self.extrapolate == "linear":
                # One ring of cells extrapolated linearly (odd reflection: 2 v[0] - v[1]), so
                # the mesh covers the whole DEM footprint with the slope continued: a block-
                # averaged sloping glacier is not flat in the outer half cell.
                ring = self.grid
                padded = Grid(
                    ring.west - ring.resolution[0],
                    ring.north + ring.resolution[1],
                    ring.resolution,
                    (ring.ny + 2, ring.nx + 2),
                    ring.crs,
                )
                points = padded.xy()
                values = np.pad(
                    self.values.reshape(ring.shape), 1, mode="reflect", reflect_type="odd"
                ).ravel()
            self._tri_points, self._tri_values = points, values
            tri = Delaunay(points)
            self._interp = LinearNDInterpolator(tri, values)
            # Boundary edges of the triangulation: the edge opposite vertex j of simplex s
            # is on the hull when s has no neighbour across it.
            s, j = np.nonzero(tri.neighbors == -1)
            ends = np.stack([tri.simplices[s, (j + 1) % 3], tri.simplices[s, (j + 2) % 3]], 1)
            self._edges = ends

    def dem(self, xy: np.ndarray) -> np.ndarray:
        """The mesh itself (m) at ``xy`` (n, 2) -> (n,), before any offset; never NaN."""
        xy = check_xy(xy)
        if self._interp is None:  # one row or column of cells: interpolate along it
            axis = 0 if self.grid.nx > 1 else 1
            order = np.argsort(self.points[:, axis])
            return np.interp(xy[:, axis], self.points[order, axis], self.values[order])
        out = self._interp(xy)
        outside = np.flatnonzero(np.isnan(out))
        for start in range(0, outside.size, _CHUNK):
            chunk = outside[start : start + _CHUNK]
            out[chunk] = self._nearest_on_hull(xy[chunk])
        return out

    def _nearest_on_hull(self, xy: np.ndarray) -> np.ndarray:
        """Value at the nearest point of the hull boundary, linear along each edge."""
        i, j = self._edges[:, 0], self._edges[:, 1]
        pts, vals = self._tri_points, self._tri_values
        a, ab = pts[i], pts[j] - pts[i]  # (e, 2)
        rel = xy[:, None, :] - a[None]  # (n, e, 2)
        t = np.clip((rel * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)  # (n, e)
        d2 = ((rel - t[..., None] * ab) ** 2).sum(-1)
        best = np.argmin(d2, axis=1)
        tb = t[np.arange(len(xy)), best]
        return vals[i[best]] + tb * (vals[j[best]] - vals[i[best]])

    def __repr__(self) -> str:
        w, s, e, n = self.grid.bounds
        return (
            f"TriangulatedMean(cells={self.grid.shape}, bounds=({w:.1f}, {s:.1f}, {e:.1f}, "
            f"{n:.1f}), crs={self.crs.to_string()}, elevation {self.values.min():.2f}.."
            f"{self.values.max():.2f} m"
            + ("" if self.offset == "none" else f", {self._coef_text()}")
            + ")"
        )


class _CheckedMean:
    """A user callable whose output is validated: shape (n,), finite."""

    def __init__(self, fn: MeanFunction) -> None:
        self.fn = fn
        self.crs = getattr(fn, "crs", None)

    def fit(self, xy: np.ndarray, z: np.ndarray) -> _CheckedMean:
        """``fn.fit(xy, z)`` wrapped again if ``fn`` has one; else this object."""
        return _CheckedMean(self.fn.fit(xy, z)) if hasattr(self.fn, "fit") else self

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        xy = check_xy(xy)
        fix = "make the mean function return one finite elevation (m) per point, shape (n,)"
        try:
            out = np.asarray(self.fn(xy), dtype=float)
        except (TypeError, ValueError) as exc:
            raise bad_input("mean", self.fn, "a callable xy (n, 2) -> (n,) metres", fix) from exc
        if out.shape != (len(xy),):
            raise bad_input("mean", f"output of shape {out.shape}", f"shape ({len(xy)},)", fix)
        if not np.all(np.isfinite(out)):
            bad = int((~np.isfinite(out)).sum())
            raise bad_input("mean", f"{bad} non-finite values", "finite elevations", fix)
        return out

    def __repr__(self) -> str:
        return f"_CheckedMean({self.fn!r})"


def as_mean_function(mean: Any) -> MeanFunction:
    """Normalise what a user passes as a GP mean.

    ``None`` or ``"constant"`` -> :class:`ConstantMean` (mean of the observations); a number
    -> ``ConstantMean(value)``; an ``xarray.DataArray`` (coarse DEM) ->
    :class:`TriangulatedMean`; a raster file path (``pathlib.Path``, or a string naming an
    existing file or ending in ``.tif``/``.tiff``/``.vrt``) or an open rasterio dataset ->
    :class:`~terrain.raster_mean.RasterMean` (a satellite DEM, ``offset="fit"``); our own mean
    objects are returned as they are; any other callable ``xy (n, 2) -> (n,)`` is wrapped so
    its output is checked (shape, finite).
    """
    from .breakline import BreaklineMean  # here: both import this module
    from .raster_mean import RasterMean

    if mean is None or (isinstance(mean, str) and mean.lower() == "constant"):
        return ConstantMean()
    if isinstance(mean, ConstantMean | OffsetScaleMean | _CheckedMean | BreaklineMean):
        return mean
    if isinstance(mean, Real) and not isinstance(mean, bool):
        return ConstantMean(float(mean))
    if isinstance(mean, xr.DataArray):
        return TriangulatedMean(mean)
    if isinstance(mean, Path) or (
        isinstance(mean, str)
        and (Path(mean).is_file() or mean.lower().endswith((".tif", ".tiff", ".vrt")))
    ):
        return RasterMean(mean)
    if all(hasattr(mean, a) for a in ("read", "transform", "crs")):  # a rasterio dataset
        return RasterMean(mean)
    if callable(mean) and not isinstance(mean, str | type):
        return _CheckedMean(mean)
    expected = (
        'None, "constant", a number, a coarse DEM DataArray, a DEM file path or a callable xy -> z'
    )
    raise bad_input("mean", mean, expected, "pass e.g. mean=coarse_dem(truth)")
