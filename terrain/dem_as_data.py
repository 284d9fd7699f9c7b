"""A satellite DEM as data: its cells as noisy samples of the ground, beside the survey's.

A prior *mean* (``RasterMean``) is trusted as exact between the survey's lines: where a DEM
is noisier than the survey's own interpolation (SRTM / GLO-30 class, metres of noise, over
smooth ice mapped by GNSS lines), the map follows the DEM's noise into every gap
(docs/terrain.md "The prior DEM's scale checked": 1.1-2.8 x the map without a prior on five
of eleven real sites). Read as data, each DEM cell is one more sample of the ground at its
centre -- ``z = DEM - a``, variance ``s^2`` -- and the GP weighs it against the survey
(co-kriging with a shared surface): near the lines the survey wins, in wide gaps the DEM.

``a`` (the DEM's datum offset) and ``s^2`` (its error as a point sample: noise plus the
ground's variation inside a cell) are measured on the survey itself: every sample is
compared with the DEM cell it falls in, ``a`` = the mean difference, ``s^2`` = the
differences' variance less the samples' own stated noise. The DEM's cells are read on their
own lattice, in their own CRS, and their centres projected exactly to the map's (no
resampling); nodata cells are left out and counted. The DEM's scale is taken as 1 (a DEM in
metres); a datum offset estimated on thousands of samples is taken as known.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import bad_input
from .raster_source import open_source
from .samples import ElevationSamples

__all__ = ["DemAsData", "DemCells", "dem_as_data"]

#: The DEM's variance as a sample is floored at this (m^2): a DEM that agrees with the survey
#: to its noise is still not exact.
MIN_DEM_VAR = 1e-4


@dataclass(frozen=True)
class DemAsData:
    """What :func:`dem_as_data` added, for provenance and the console.

    Attributes
    ----------
    n_cells : int
        DEM cells added as samples.
    n_nodata : int
        Cells over the area left out (nodata).
    offset_m : float
        ``a``: the DEM minus the survey, mean over the survey's samples, m.
    sd_m : float
        ``s``: the DEM's 1-sigma as a point sample of the ground, m.
    n_compared : int
        Survey samples compared with their DEM cell.
    """

    n_cells: int
    n_nodata: int
    offset_m: float
    sd_m: float
    n_compared: int

    def note(self) -> str:
        return (
            f"prior DEM as data: {self.n_cells} cells as samples (datum offset "
            f"{self.offset_m:+.2f} m and 1-sigma {self.sd_m:.2f} m from {self.n_compared} survey "
            f"samples in its cells; {self.n_nodata} nodata cells left out)"
        )


def dem_as_data(
    dem: Any,
    samples: ElevationSamples,
    bounds: tuple[float, float, float, float],
    source_crs: Any = None,
) -> tuple[ElevationSamples, DemAsData]:
    """``samples`` followed by the DEM's cells over ``bounds`` as samples of the ground.

    Parameters
    ----------
    dem : str, pathlib.Path, rasterio dataset or xarray.DataArray
        The DEM (any CRS; metres).
    samples : ElevationSamples
        The survey, in the map's projected CRS (m).
    bounds : (west, south, east, north)
        The map's area, map CRS (m); the DEM's cells whose centres fall inside are added.
    source_crs : CRS-like, optional
        The DEM's CRS when it records none.

    Returns
    -------
    samples : ElevationSamples
        The survey's samples first (same order), then the DEM's cells: ``z = DEM - a``,
        ``z_var = s^2`` (``extra`` columns dropped: they describe the survey).
    record : DemAsData

    Raises
    ------
    InputError
        No CRS on the samples; the DEM without a valid cell over the area or under the
        survey.
    """
    return DemCells.read(dem, samples.crs, bounds, source_crs).as_samples(samples)


@dataclass(frozen=True)
class DemCells:
    """A DEM's cells over a map's area, read once (:meth:`read`), as samples of any survey
    of that area (:meth:`as_samples`): the held-out folds of
    :func:`terrain.dem_choice.choose_dem_reading` compare each fold's survey with the same
    cells without reading the DEM again.

    Attributes
    ----------
    values : ndarray of shape (rows, cols)
        The DEM's cells over the area (NaN: nodata), m.
    transform : affine.Affine
        Their transform, in the DEM's CRS.
    to_source : pyproj.Transformer
        Map CRS -> the DEM's CRS.
    xy : ndarray of shape (k, 2)
        The valid cells' centres inside the area, map CRS, m.
    z : ndarray of shape (k,)
        Their values, m.
    n_nodata : int
        Cells over the area left out (nodata).
    """

    values: np.ndarray
    transform: Any
    to_source: Any
    xy: np.ndarray
    z: np.ndarray
    n_nodata: int

    @classmethod
    def read(
        cls,
        dem: Any,
        crs: Any,
        bounds: tuple[float, float, float, float],
        source_crs: Any = None,
    ) -> DemCells:
        """The cells of ``dem`` whose centres fall inside ``bounds`` (map ``crs``, m; the
        survey's, None an :class:`InputError`)."""
        from pyproj import Transformer

        if crs is None:
            fix = "build ElevationSamples(crs=...)"
            raise bad_input("samples.crs", None, "the map's CRS", fix)

        src = open_source(dem, source_crs)
        to_src = Transformer.from_crs(crs, src.crs, always_xy=True)
        to_map = Transformer.from_crs(src.crs, crs, always_xy=True)
        w, s, e, n = bounds
        bx, by = to_src.transform([w, e, e, w], [s, s, n, n])
        values, t = src.read((min(bx), min(by), max(bx), max(by)), pad=1)
        rows, cols = np.indices(values.shape)  # axis-aligned (raster_source checks it)
        cx, cy = t.c + t.a * (cols.ravel() + 0.5), t.f + t.e * (rows.ravel() + 0.5)  # centres
        mx, my = to_map.transform(cx, cy)
        inside = (mx >= w) & (mx <= e) & (my >= s) & (my <= n)
        v = values.ravel()
        valid = inside & np.isfinite(v)
        xy = np.column_stack([np.asarray(mx)[valid], np.asarray(my)[valid]])
        n_nodata = int((inside & ~np.isfinite(v)).sum())
        return cls(values, t, to_src, xy, v[valid], n_nodata)

    def as_samples(self, samples: ElevationSamples) -> tuple[ElevationSamples, DemAsData]:
        """``samples`` followed by the cells, their offset and 1-sigma measured on
        ``samples`` (:func:`dem_as_data`)."""
        t, values = self.transform, self.values
        # the survey against the DEM cell each sample falls in
        sx, sy = self.to_source.transform(samples.xy[:, 0], samples.xy[:, 1])
        c = np.floor((np.asarray(sx) - t.c) / t.a).astype(int)
        r = np.floor((np.asarray(sy) - t.f) / t.e).astype(int)
        ok = (r >= 0) & (r < values.shape[0]) & (c >= 0) & (c < values.shape[1])
        under = np.full(samples.n, np.nan)
        under[ok] = values[r[ok], c[ok]]
        diff = under - samples.z
        comp = np.isfinite(diff)
        if not self.z.size or comp.sum() < 2:
            raise bad_input(
                "prior DEM",
                f"{self.z.size} valid cells over the map, {int(comp.sum())} under the survey",
                "a DEM with data over the map and under the survey",
                "check the DEM's extent and nodata",
            )
        # sums over sorted values: the same bits in any row order of the survey
        d, noise = np.sort(diff[comp]), np.sort(samples.z_var[comp])
        a = float(np.mean(d))
        var = float(np.mean(np.sort((d - a) ** 2))) - float(np.mean(noise))
        var = max(var, MIN_DEM_VAR)
        k = self.z.size
        out = ElevationSamples(
            np.vstack([samples.xy, self.xy]),
            np.concatenate([samples.z, self.z - a]),
            np.concatenate([samples.z_var, np.full(k, var)]),
            crs=samples.crs,
        )
        record = DemAsData(
            n_cells=k,
            n_nodata=self.n_nodata,
            offset_m=a,
            sd_m=float(np.sqrt(var)),
            n_compared=int(comp.sum()),
        )
        return out, record
