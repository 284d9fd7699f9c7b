"""Geometric anisotropy: ground smoother along one azimuth than across it, given or chosen.

Real terrain is rarely isotropic. A valley glacier is smooth along its flow and curved
across it; moraines, crevasse fields and sastrugi have a grain. Measured on the real DEMs of
``scripts/real_dems.py`` (half the mean squared elevation difference at 25 m along four
azimuths): the largest over the smallest is 1.2-1.6 on olinda, rm, volcano, topobathy and
lux, 1.9-2.9 on clm, bei, jacksboro and prism, 4.5-5.4 on gorillas and glacier. An isotropic
kernel fitted to a rover's survey learns the average; where the tracks run along the smooth
direction the map is over-confident in the gaps between them (bei with 2 % scattered samples
at 3,000: 65.2 % of the truth inside +-1 sigma) and held-out samples cut from the tracks,
predicted along the smooth direction, say the opposite (75 %): docs/terrain.md "Anisotropic
ground".

The model is the geometric anisotropy of geostatistics (Journel & Huijbregts 1978,
*Mining Geostatistics*, III.B.4; PyKrige's ``anisotropy_angle`` / ``anisotropy_scaling``):
``k(x, x') = k_iso(|A (x - x')|)`` with ``A`` a rotation to the ground's axes followed by a
compression of the smooth (major) axis by ``ratio``. Every kernel part shares it, so the
transformed coordinates ``A x`` carry an isotropic kernel and every path of the engine
(Vecchia fits, tiles, compiled loops, the microscale part) works unchanged on them.
Distances in that space are never longer than in metres: the kernel's length scales are
the metric ones *across* the grain, ``ratio`` times longer along it.

Choice (``anisotropy="auto"``, :func:`select_anisotropy`, before the kernel search, which
then runs in the chosen coordinates): a pilot Matern 5/2 is fitted isotropic on the fit
subset and its Vecchia likelihood (Eq 9) profiled over :data:`AZIMUTHS` x :data:`RATIOS`
in the area-preserving form ``diag(1/sqrt(r), sqrt(r)) R`` (the isotropic length is then
the geometric mean of the two, a fair start), then refined around the best
(:data:`REFINE_ROUNDS`); the best is refitted and kept when its BIC beats the isotropic
refit's by :data:`MIN_DELTA_BIC`, two more parameters charged. Every profile plan shares
one random order (common random numbers), so the comparison is of the geometry, not of the
order.

Not the default (``TerrainGP(anisotropy=None)``). It recovers a known grain (ratio 3 at 60
deg: 61.9 deg, 3.07; RMSE -39 %) and helps bei surveyed along its smooth axis (RMSE -6 %,
68 % coverage 65.2 -> 68.2), but on the real-DEM benchmark at 3,000 samples the evidence
kept grains on 11 of 22 rows and four maps lost 3-5 %: the fit subset's pairs lie along the
tracks and across one swath, and a grain learnt there is extrapolated across the gaps
where the map's errors are (the exact Eq 9 agrees with the Vecchia one; docs/terrain.md
"Anisotropic ground").
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from .errors import NumericalError, bad_input
from .kernel_search import SCREEN_FTOL, FamilySearch, nugget_start

__all__ = [
    "AZIMUTHS",
    "MIN_DELTA_BIC",
    "RATIOS",
    "Anisotropy",
    "as_anisotropy",
    "choose_anisotropy",
    "select_anisotropy",
]

#: Azimuths of the smooth axis tried, degrees clockwise from grid north (0-180: an axis).
AZIMUTHS = tuple(np.arange(0.0, 180.0, 22.5))
#: Ratios of the length scale along the smooth axis to the one across it, tried.
RATIOS = (1.5, 2.25, 3.4, 5.0)
#: Rounds of the local refinement around the profile's best (steps halved each round).
REFINE_ROUNDS = 2
#: Largest ratio the refinement reaches.
MAX_RATIO = 8.0
#: BIC improvement (two more parameters included) the anisotropy needs over the isotropic
#: kernel: "strong" evidence (Kass & Raftery 1995), as the kernel search's near ties.
MIN_DELTA_BIC = 6.0


@dataclass(frozen=True)
class Anisotropy:
    """A geometric anisotropy: the ground's length scale along ``azimuth_deg`` is ``ratio``
    times the one across it.

    Parameters
    ----------
    azimuth_deg : float
        Azimuth of the smooth (major) axis, degrees clockwise from grid north, in [0, 180).
    ratio : float
        Length along the major axis over length across it, >= 1 (1: isotropic).
    """

    azimuth_deg: float = 0.0
    ratio: float = 1.0

    def __post_init__(self) -> None:
        az, r = float(self.azimuth_deg), float(self.ratio)
        if not math.isfinite(az):
            raise bad_input("azimuth_deg", self.azimuth_deg, "a finite angle", "e.g. 30.0")
        if not (math.isfinite(r) and r >= 1.0):
            fix = "e.g. Anisotropy(azimuth_deg=30.0, ratio=2.0); 1.0 is isotropic"
            raise bad_input("ratio", self.ratio, "a ratio >= 1 of the two length scales", fix)
        object.__setattr__(self, "azimuth_deg", az % 180.0)
        object.__setattr__(self, "ratio", r)

    @property
    def isotropic(self) -> bool:
        return self.ratio == 1.0

    def matrix(self, area_preserving: bool = False) -> np.ndarray:
        """The 2 x 2 map ``A`` from (easting, northing) to the kernel's coordinates: rows are
        the major axis (compressed by ``ratio``) and the minor axis. ``area_preserving``:
        ``diag(1/sqrt(r), sqrt(r))`` instead of ``diag(1/r, 1)``."""
        a = math.radians(self.azimuth_deg)
        rot = np.array([[math.sin(a), math.cos(a)], [math.cos(a), -math.sin(a)]])
        r = self.ratio
        scale = (1.0 / math.sqrt(r), math.sqrt(r)) if area_preserving else (1.0 / r, 1.0)
        return np.diag(scale) @ rot

    @property
    def kernel_matrix(self) -> np.ndarray | None:
        """:meth:`matrix` of the kernel's space, or None when isotropic (no transform)."""
        return None if self.isotropic else self.matrix()

    def apply(self, xy: np.ndarray, area_preserving: bool = False) -> np.ndarray:
        """Coordinates (n, 2), m, in the kernel's space (the input itself when isotropic)."""
        if self.isotropic:
            return xy
        return np.asarray(xy, dtype=float) @ self.matrix(area_preserving).T

    def describe(self) -> str:
        if self.isotropic:
            return "isotropic"
        return (
            f"geometric anisotropy: length scales {self.ratio:.3g} x longer along azimuth "
            f"{self.azimuth_deg:.1f} deg (clockwise from grid north) than across it"
        )

    def to_dict(self) -> dict[str, float]:
        return {"azimuth_deg": self.azimuth_deg, "ratio": self.ratio}


def as_anisotropy(value: Any) -> Anisotropy | str | None:
    """Validate ``TerrainGP(anisotropy=...)``: ``"auto"``, ``None`` (isotropic) or an
    :class:`Anisotropy`."""
    if value is None or isinstance(value, Anisotropy):
        return value
    if isinstance(value, str) and value == "auto":
        return value
    raise bad_input(
        "anisotropy",
        value,
        '"auto" (chosen by evidence with kernel="auto"), None (isotropic) or an Anisotropy',
        "e.g. anisotropy=terrain.Anisotropy(azimuth_deg=30.0, ratio=2.0)",
    )


def _lml(search: Any, kernel: Any, nugget: float) -> float | None:
    try:
        return float(search.lml(kernel, nugget))
    except NumericalError:
        return None


def choose_anisotropy(
    search_at: Any, kernel: Any, nugget: float, n: int, pool: Any = None
) -> tuple[Anisotropy, dict[str, Any]]:
    """The geometry kept for ``kernel`` (an isotropic fit: the pilot) by the profile and BIC.

    Parameters
    ----------
    search_at : callable
        ``search_at(matrix) -> search``: a kernel search (``lml``, ``optimize``) on the fit
        subset in the coordinates ``X @ matrix.T``, every one with the same random order.
    kernel, nugget
        The isotropic fit and its nugget (m^2).
    n : int
        Fit-subset size (the BIC's penalty is ``2 ln n`` for the two parameters).
    pool : concurrent.futures.Executor, optional
        Evaluates the profile's geometries side by side (same numbers in any case).

    Returns
    -------
    anisotropy : Anisotropy
        The kept geometry (isotropic unless the evidence is strong); the kernel search then
        fits its kernel in that geometry's coordinates.
    record : dict
        ``azimuth_deg, ratio`` of the profile's best, ``lml_isotropic``, ``lml_anisotropic``
        (nats, both refitted under the common order), ``delta_bic`` (isotropic minus
        anisotropic, two parameters charged) and ``kept``.
    """
    geoms = [Anisotropy(a, r) for a in AZIMUTHS for r in RATIOS]

    def profile(geom: Anisotropy) -> float | None:
        return _lml(search_at(geom.matrix(area_preserving=True)), kernel, nugget)

    def best_of(geoms: list[Anisotropy], best: tuple[float, Anisotropy] | None):
        values = list(pool.map(profile, geoms) if pool is not None else map(profile, geoms))
        for v, g in zip(values, geoms, strict=True):
            if v is not None and (best is None or v > best[0]):
                best = (v, g)
        return best

    found = best_of(geoms, None)
    record: dict[str, Any] = {"kept": False}
    if found is None:
        return Anisotropy(), record
    # then around the best, the steps halved each round (azimuth; ratio on a log scale)
    step_az, step_r = AZIMUTHS[1] / 2.0, math.sqrt(RATIOS[1] / RATIOS[0])
    for _ in range(REFINE_ROUNDS):
        g0 = found[1]
        moves = [(da, f) for da in (-step_az, 0.0, step_az) for f in (1 / step_r, 1.0, step_r)]
        near = [
            Anisotropy(g0.azimuth_deg + da, min(max(g0.ratio * f, 1.0), MAX_RATIO))
            for da, f in moves
            if (da, f) != (0.0, 1.0)
        ]
        found = best_of(near, found)
        step_az, step_r = step_az / 2.0, math.sqrt(step_r)
    best = found[1]

    def refit(geom: Anisotropy) -> float | None:  # the refitted likelihood, nats
        fit = search_at(geom.matrix(area_preserving=True)).optimize(kernel, nugget)
        return None if fit is None else fit[2]

    pair = list(pool.map(refit, (Anisotropy(), best)) if pool else map(refit, (Anisotropy(), best)))
    iso, aniso = pair
    record.update(best.to_dict())
    if iso is None or aniso is None:
        return Anisotropy(), record
    delta = 2.0 * (aniso - iso) - 2.0 * math.log(n)
    record.update(lml_isotropic=iso, lml_anisotropic=aniso, delta_bic=delta)
    if delta < MIN_DELTA_BIC:
        return Anisotropy(), record
    record["kept"] = True
    return best, record


def select_anisotropy(
    X: np.ndarray,
    r: np.ndarray,
    z_var: np.ndarray,
    *,
    fit_nugget: bool,
    nugget: float,
    nugget_bounds: Any,
    spacing: float,
    rng: np.random.Generator,
    m: int = 10,
    workers: int | None = None,
) -> tuple[Anisotropy, dict[str, Any]]:
    """The ground's geometric anisotropy, before the kernel search (which then runs in its
    coordinates): a pilot Matern 5/2 fitted isotropic on the fit subset, its likelihood
    profiled over azimuths and ratios, kept on strong evidence
    (:func:`terrain.anisotropy.choose_anisotropy`).

    Parameters are those of :func:`terrain.kernel_search.select_kernel` (``X`` centred, m;
    ``m`` the Vecchia conditioning-set size, ``workers`` the threads); ``rng`` orders the one
    Vecchia plan order every geometry shares (pass a child stream: the caller's stream is
    not drawn from). Returns the geometry and its record (``pilot`` kernel repr added).
    """
    order = rng.bit_generator.seed_seq
    args = (r, z_var, fit_nugget, nugget, nugget_bounds, spacing, m)

    def search_at(matrix: np.ndarray) -> FamilySearch:
        return FamilySearch(X @ matrix.T, *args, np.random.default_rng(order), SCREEN_FTOL)

    pilot_search = search_at(np.eye(2))
    pilot = pilot_search.single("matern52", nugget_start(pilot_search, *args[2:5]))
    if pilot is None:
        return Anisotropy(), {"kept": False, "pilot": None}
    workers = max(1, workers if workers is not None else os.cpu_count() or 1)
    with threadpool_limits(1), ThreadPoolExecutor(max_workers=workers) as pool:
        geometry, record = choose_anisotropy(search_at, pilot[0], pilot[1], r.size, pool)
    record["pilot"] = repr(pilot[0])
    return geometry, record
