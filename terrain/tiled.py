"""Tiled local GP prediction: exact GPs on overlapping tiles, blended into one seamless map.

The kernel matrix of 50,000 landmarks does not fit a laptop (docs/architecture.md §5: the exact GP
stops near 10k points on 2 cores), but at rover-scale length scales (~15 m) a cell's
posterior depends on the data within a few length scales. So the query domain is cut into
square tiles of side ``tile``; each tile gets an exact GP (R&W Alg. 2.1) on the samples
within ``halo`` of its blending region, and predicts the cells of its core plus a
``blend`` margin. Where neighbouring tiles overlap, a smoothstep partition of unity
``w_t(x)`` (weights sum to one everywhere) combines them:

    mean(x) = sum_t w_t mu_t(x)
    var(x)  = sum_t w_t (sigma_t^2(x) + mu_t(x)^2) - mean(x)^2      (law of total variance)

so mean and std are continuous across tile borders — no seams. Hyperparameters, per-point
noise, the nugget and the prior mean are exactly those of the exact GP. A tile without data
predicts the prior mean with the prior variance.

Optionally (``amplitude_prior_sd``) each tile scales the kernel by its own amplitude ``s_t``
(length scales and noise shared): ``k_t = s_t k``, ``s_t`` the maximum a posteriori value of
Eq 9 on the samples in the tile's blending region under a log-normal prior centred on the
global fit (:func:`local_amplitude`). Terrain is rougher near crevasses and melt pools than
on plain snow; one stationary variance is too large for most of the map and too small there.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import minimize_scalar

from .errors import TilingWarning, bad_input
from .gaps import largest_gap, sample_density
from .linalg import cholesky_jitter
from .microscale import without_microscale
from .nogil_lapack import cho_solve_lower, solve_lower, symmetric_eigen
from .radial_table import tabulate
from .tile_selection import capped_selection

__all__ = [
    "TileSpec",
    "default_tiles",
    "halo_for_gaps",
    "largest_gap",
    "local_amplitude",
    "long_scale_part",
    "predict_tiled",
    "sample_density",
    "shortest_lengthscale",
    "tiles_reaching_gaps",
]

#: Most samples (nearest the tile centre) a tile's amplitude is estimated from.
AMPLITUDE_POINTS = 150
#: Search range of a tile's amplitude, relative to the global kernel variance.
AMPLITUDE_BOUNDS = (1e-3, 1e3)
#: Cells per block of a tile's prediction.
QUERY_CHUNK = 256
#: Largest halo of the default tiles, m.
MAX_HALO = 150.0
#: Share of a tile's sample budget (``max_points``) its blending region may hold at the
#: samples' mean density; the rest is for the margin beyond it. At 50,000 samples on
#: 600 m x 600 m this capped default tiles at 37 m (34 m at the budget of 500): 64 m
#: tiles held ~870 samples in their region against a budget of 600, and their grid RMSE
#: was 3-21 % above that of 40 m tiles on five real DEMs (docs/terrain.md "Tiles sized to
#: their sample budget").
REGION_SHARE = 0.5


@dataclass(frozen=True)
class TileSpec:
    """Geometry of the tiled GP, metres.

    Parameters
    ----------
    tile : float
        Side of a tile's core, m.
    blend : float
        Half-width of the overlap over which neighbouring tiles are blended, m
        (0 < blend <= tile / 2).
    halo : float
        Data margin beyond a tile's blending region, m (about 3 length scales: the data
        that still matter for a cell).
    max_points : int
        Cap on samples per tile; beyond it the samples nearest the tile are kept (in dense
        data the nearest ones screen the rest). 500 since session 28: the triangular
        solves cost max_points^2 per cell; against 600, 50k samples -> 600 x 600 at 1 m
        predicted in 8.8-8.9 s instead of 10.5-11.9 (map_speed_s28*.json), standings the same but
        one held-out row at 50k (docs/terrain.md "Performance notes").
    far_share : float
        Share of ``max_points`` a capped tile spreads over its halo instead of taking the
        nearest (0, the default: the nearest only). With a halo of three long length
        scales it brings a tiled fit close to the exact GP across gaps between dense lines;
        measured, not the default (docs/terrain.md "A capped tile's budget spread").
    """

    tile: float = 32.0
    blend: float = 4.0
    halo: float = 45.0
    max_points: int = 500
    far_share: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.tile) and self.tile > 0):
            raise bad_input("tile", self.tile, "a positive tile side in m", "e.g. tile=32")
        if not (0 < self.blend <= self.tile / 2):
            raise bad_input(
                "blend",
                self.blend,
                f"0 < blend <= tile / 2 = {self.tile / 2}",
                "use a smaller blend or larger tiles",
            )
        if not (np.isfinite(self.halo) and self.halo >= 0):
            raise bad_input("halo", self.halo, "a data margin >= 0 in m", "about 3 length scales")
        if int(self.max_points) < 3:
            raise bad_input("max_points", self.max_points, ">= 3 samples per tile", "")
        if not (0.0 <= self.far_share < 1.0):
            raise bad_input("far_share", self.far_share, "0 <= far_share < 1", "e.g. 0.5")

    def describe(self, amplitude_prior_sd: float | None = None) -> str:
        """One line for a product's provenance."""
        amp = (
            ""
            if amplitude_prior_sd is None
            else f", local amplitude (prior sd {amplitude_prior_sd:g})"
        )
        far = f", {100 * self.far_share:g} % of them spread over the halo" if self.far_share else ""
        return (
            f"tiled local GP (tile {self.tile:g} m, blend {self.blend:g} m, halo {self.halo:g}"
            f" m, at most {self.max_points} samples per tile{far}{amp})"
        )

    @classmethod
    def for_lengthscale(cls, lengthscale: float, density: float | None = None) -> TileSpec:
        """Defaults scaled to a (shortest) kernel length scale in metres, and to the samples'
        mean density (samples per m^2) when given.

        The tile is twice the length scale (16-64 m), but no larger than the side whose
        blending region holds :data:`REGION_SHARE` of ``max_points`` at ``density``: a tile
        whose own region fills its sample budget sees nothing beyond its edges and drops
        samples inside it (docs/terrain.md "Tiles sized to their sample budget").
        """
        ls = float(lengthscale)
        tile = float(np.clip(2.0 * ls, 16.0, 64.0))
        if density is not None and np.isfinite(density) and density > 0:
            # (tile + 2 blend)^2 * density = REGION_SHARE * max_points, blend = tile / 8
            budget = np.sqrt(REGION_SHARE * cls.max_points / density) / 1.25
            tile = float(max(16.0, min(tile, budget)))
        return cls(tile=tile, blend=tile / 8.0, halo=float(np.clip(3.0 * ls, 10.0, MAX_HALO)))


def long_scale_part(kernel, halo: float):
    """The kernel part (if any) whose length scale exceeds ``halo`` while its variance is at
    least a tenth of the shortest-scale part's: what a tiled GP cannot represent. A
    :class:`terrain.microscale.Microscale` part is not counted."""
    parts = without_microscale(kernel)
    short = min(parts, key=lambda p: float(np.min(p.lengths)))
    for p in parts:
        if float(np.min(p.lengths)) > halo and p.variance >= 0.1 * short.variance:
            return p
    return None


def halo_for_gaps(spec: TileSpec, kernel, widest: float) -> TileSpec:
    """``spec`` with the halo of its long-scale kernel part (three of that part's length
    scales) when that part would otherwise leave a tile without data, the longer halo
    reaches across the survey's widest gap and it is no more than :data:`MAX_HALO`; else
    ``spec`` itself (a longer part keeps the exact route or the warning: tiles with a 150 m
    halo and a 400 m Matérn part left the mean 0.35 m off the exact GP's in a 60 m gap).

    The default halo is three *shortest* length scales. A kernel whose short part is faint
    (precise samples: SE 15 m + SE 3.9 m carrying 1.6 % of the variance) gets a 12 m halo,
    its 15 m part counts as long, and 18 m gaps sent 7,200 samples to the exact route
    (docs/terrain.md "Performance notes"). Sized by the long part, the tiles see the data
    that part needs and match the exact GP (measured there: 1-sigma within 1 %, RMSE 0.0724
    against 0.0722 m; a halo of just the widest gap left the mean 0.4 m off in places).
    """
    long_part = long_scale_part(kernel, spec.halo)
    if long_part is None or widest <= spec.halo:
        return spec
    halo = 3.0 * float(np.min(long_part.lengths))
    return replace(spec, halo=halo) if widest <= halo <= MAX_HALO else spec


def default_tiles(
    kernel, xy: np.ndarray, widest: float | None = None, matrix: np.ndarray | None = None
) -> TileSpec:
    """The tiles a fit builds for ``kernel`` on samples at ``xy`` (n, 2), m, when the user
    gives none: sized by the shortest length scale and the samples' mean density
    (:meth:`TileSpec.for_lengthscale`), the halo grown for a long-scale part
    (:func:`halo_for_gaps`). ``widest``: the samples' :func:`largest_gap` when known;
    ``matrix``: ``xy`` are in an anisotropy's kernel space (:func:`sample_density`)."""
    widest = largest_gap(xy, matrix=matrix) if widest is None else widest
    spec = TileSpec.for_lengthscale(shortest_lengthscale(kernel), sample_density(xy, matrix))
    return halo_for_gaps(spec, kernel, widest)


def tiles_reaching_gaps(kernel, xy: np.ndarray, matrix: np.ndarray | None = None) -> TileSpec:
    """:func:`default_tiles` whose halo also reaches across the samples' widest gap when a
    long-scale kernel part needs data there.

    For a cross-validation fold with the map's kernel held fixed: its held-out blocks open
    gaps that the map does not have, 0.3-2.3 m wider than the map's halo on a real DEM
    (rm, 80-node window, 3,000 samples), and each fold's fit warned that *the map* would
    revert to its prior mean. A tile's data are capped at ``max_points`` nearest samples,
    so the longer halo costs nothing where data are dense. ``matrix``: as
    :func:`default_tiles`.
    """
    widest = largest_gap(xy, matrix=matrix)
    spec = default_tiles(kernel, xy, widest, matrix)
    if long_scale_part(kernel, spec.halo) is not None and widest > spec.halo:
        spec = replace(spec, halo=widest)
    return spec


def shortest_lengthscale(kernel) -> float:
    """The shortest length scale of a kernel or of any part of a sum, m (a
    :class:`terrain.microscale.Microscale` part not counted)."""
    parts = without_microscale(kernel)
    return float(min(np.min(p.lengths) for p in parts))


def local_amplitude(
    K: np.ndarray, resid: np.ndarray, noise_var: np.ndarray, prior_sd: float
) -> float:
    """MAP amplitude ``s`` of ``s * K + diag(noise_var)`` for residuals ``resid`` (Eq 9).

    Maximizes ``log p(resid | s) + log N(log s; 0, prior_sd^2)`` over ``log s`` in
    :data:`AMPLITUDE_BOUNDS`. With ``D = diag(noise_var)^(-1/2)`` and ``D K D = U diag(lam) U^T``
    (one eigendecomposition), ``log p = -1/2 sum(c_j^2 / (1 + s lam_j)) - 1/2 sum(log(1 +
    s lam_j)) + const`` with ``c = U^T D resid``: every trial ``s`` costs O(n).

    Parameters
    ----------
    K : ndarray of shape (n, n)
        Kernel matrix at the global hyperparameters (no noise), m^2.
    resid : ndarray of shape (n,)
        Samples minus the prior mean, m.
    noise_var : ndarray of shape (n,)
        Per-sample noise variance including the nugget, m^2 (floored at 1e-10 of the mean
        kernel diagonal so that D exists).
    prior_sd : float
        Standard deviation of ``log s`` under the prior (1.0: a factor e at one sigma).

    Returns
    -------
    float
        The amplitude ``s`` (1.0, the global fit, for fewer than 3 samples).
    """
    n = resid.size
    if n < 3:
        return 1.0
    floor = 1e-10 * float(np.mean(np.diag(K)))
    d = 1.0 / np.sqrt(np.maximum(noise_var, floor))
    lam, U = symmetric_eigen(K * d[:, None] * d[None, :])  # GIL released (nogil_lapack)
    lam = np.maximum(lam, 0.0)
    c2 = (U.T @ (resid * d)) ** 2

    def neg_log_post(u: float) -> float:
        a = 1.0 + np.exp(u) * lam
        return 0.5 * float(np.sum(c2 / a) + np.sum(np.log(a))) + 0.5 * (u / prior_sd) ** 2

    lo, hi = np.log(AMPLITUDE_BOUNDS)
    res = minimize_scalar(neg_log_post, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    return float(np.exp(res.x))


def _smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)  # S(t) + S(1 - t) = 1: the weights sum to one


def _weights_1d(u: np.ndarray, tile: float, blend: float) -> np.ndarray:
    """Weight of a tile at offset ``u`` from its left edge: rises over [-B, B], falls over
    [T - B, T + B]."""
    return _smoothstep((u + blend) / (2 * blend)) * _smoothstep((tile + blend - u) / (2 * blend))


def _buckets(ij: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
    """Indices grouped by integer cell (i, j)."""
    order = np.lexsort((ij[:, 1], ij[:, 0]))
    keys = ij[order]
    cut = np.flatnonzero(np.any(np.diff(keys, axis=0) != 0, axis=1)) + 1
    return {tuple(ij[g[0]]): g for g in np.split(order, cut) if g.size} if order.size else {}


def predict_tiled(
    xq: np.ndarray,
    X: np.ndarray,
    resid: np.ndarray,
    noise_var: np.ndarray,
    kernel,
    spec: TileSpec,
    return_std: bool = True,
    workers: int | None = None,
    amplitude_prior_sd: float | None = None,
    basis: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray | None, dict[str, float]]:
    """Blended local-GP posterior of the residual at ``xq``.

    Parameters
    ----------
    xq : ndarray of shape (m, 2)
        Query points (centred coordinates, m).
    X : ndarray of shape (n, 2)
        Sample locations (same frame).
    resid : ndarray of shape (n,)
        Samples minus the prior mean, m.
    noise_var : ndarray of shape (n,)
        Per-sample noise variance including the nugget, m^2.
    kernel : Kernel
        Covariance with fitted hyperparameters.
    spec : TileSpec
        Tile geometry.
    return_std : bool
        Also compute the posterior 1-sigma.
    workers : int, optional
        Threads over tiles (default: the number of CPUs).
    basis : (H, Hq, cov), optional
        A linear mean's basis at the samples (n, p) and at the queries (m, p) and its
        coefficients' covariance (p, p): each tile adds ``R^T cov R``,
        ``R = h* - H_t K_t^-1 k*`` (R&W Eq 2.42 on the tile's data).
    amplitude_prior_sd : float, optional
        Give each tile its own kernel amplitude (:func:`local_amplitude`, from the samples in
        its blending region, at most :data:`AMPLITUDE_POINTS` nearest its centre) with this
        prior standard deviation of its log; ``None``: one stationary kernel.

    Returns
    -------
    mean : ndarray of shape (m,)
        Posterior mean of the residual, m.
    std : ndarray of shape (m,) or None
        Posterior 1-sigma, m.
    stats : dict
        ``tiles``, ``max_points_used``, ``tiles_capped`` (tiles whose data were cut to
        ``max_points``), ``max_jitter``; with local amplitudes also ``amplitudes``: the 5th,
        50th and 95th percentiles of the tiles' ``s``.
    """
    from concurrent.futures import ThreadPoolExecutor

    from threadpoolctl import threadpool_limits

    T, B, H = spec.tile, spec.blend, spec.halo
    # A lattice anchored at multiples of T in the (centred) frame, not at the queries: every
    # block of a chunked map uses the same tiles, so blocks join exactly.
    origin = (np.floor(xq.min(axis=0) / T) - 1.0) * T
    q_buckets = _buckets(np.floor((xq - origin) / T).astype(np.int64))
    d_buckets = _buckets(np.floor((X - origin) / T).astype(np.int64))
    reach = int(np.ceil((B + H) / T))
    prior_var = float(kernel.diag(xq[:1])[0])
    # Kernel matrices from a distance table (terrain.radial_table): one lookup an entry in
    # place of an exponential a part. Distances within a tile reach the diagonal of its
    # blending region plus a halo on either side.
    table = tabulate(kernel, np.sqrt(2.0) * (T + 2 * B) + 2 * H)

    def matrix(A: np.ndarray, C: np.ndarray | None = None, amp: float | None = None):
        """The kernel matrix of A and C (A's own without C), times a tile's amplitude."""
        if table is not None:
            return table(A, C, amp)
        M = kernel(A, C)
        if amp is not None:
            M *= amp
        return M

    # Every tile that some query touches: the query's own tile and, near an edge, neighbours.
    tiles = sorted({(i + a, j + b) for (i, j) in q_buckets for a in (-1, 0, 1) for b in (-1, 0, 1)})

    def one_tile(ij: tuple[int, int]):
        i, j = ij
        lo = origin + np.array([i, j]) * T  # tile core lower-left corner
        # Queries in the blending region [lo - B, lo + T + B)^2 (from the 3x3 buckets).
        q_idx = [
            q_buckets[(i + a, j + b)]
            for a in (-1, 0, 1)
            for b in (-1, 0, 1)
            if (i + a, j + b) in q_buckets
        ]
        q_idx = np.concatenate(q_idx)
        u = xq[q_idx] - lo
        w = _weights_1d(u[:, 0], T, B) * _weights_1d(u[:, 1], T, B)
        keep = w > 0
        q_idx, w = q_idx[keep], w[keep]
        if q_idx.size == 0:
            return None
        d_idx = [
            d_buckets[(i + a, j + b)]
            for a in range(-reach, reach + 1)
            for b in range(-reach, reach + 1)
            if (i + a, j + b) in d_buckets
        ]
        capped, jitter = False, 0.0
        if d_idx:
            d_idx = np.concatenate(d_idx)
            # Distance from each sample to the tile's blending region (0 inside it).
            gap = np.maximum(np.maximum(lo - B - X[d_idx], X[d_idx] - (lo + T + B)), 0.0)
            dist = np.hypot(gap[:, 0], gap[:, 1])
            near = dist <= H
            d_idx, dist = d_idx[near], dist[near]
            if d_idx.size > spec.max_points:
                capped = True
                d_idx = d_idx[capped_selection(X[d_idx], dist, spec.max_points, spec.far_share)]
        if len(d_idx) == 0:
            var0 = np.full(q_idx.size, prior_var)
            if basis is not None:
                hq = basis[1][q_idx]
                var0 = var0 + np.einsum("qi,ij,qj->q", hq, basis[2], hq)
            return q_idx, w, np.zeros(q_idx.size), var0, 0, False, 0.0, None
        d_idx = np.sort(d_idx)  # a fixed order: results independent of bucket order
        Xd = X[d_idx]
        amp = None
        if amplitude_prior_sd is not None:
            # The tile's own samples: those in its blending region, nearest the centre first.
            inside = np.flatnonzero(np.all((Xd >= lo - B) & (Xd <= lo + T + B), axis=1))
            r = np.hypot(*(Xd[inside] - (lo + T / 2)).T)
            sub = inside[np.argsort(r, kind="stable")[:AMPLITUDE_POINTS]]
            amp = local_amplitude(
                matrix(Xd[sub]), resid[d_idx[sub]], noise_var[d_idx[sub]], amplitude_prior_sd
            )
        K = matrix(Xd, None, amp)
        scale = 1.0 if amp is None else amp
        K[np.diag_indices_from(K)] += noise_var[d_idx]
        # The factor and the solves below release the GIL (terrain.nogil_lapack), so the
        # tiles' threads run side by side.
        L, jitter = cholesky_jitter(K, what=f"tile ({i}, {j}) kernel matrix")
        alpha = cho_solve_lower(L, resid[d_idx])  # R&W Alg. 2.1 line 3
        W = None
        if return_std and basis is not None:
            W = solve_triangular(L, basis[0][d_idx], lower=True, check_finite=False)
        mu = np.empty(q_idx.size)
        var = np.empty(q_idx.size) if return_std else None
        # Cells in blocks of QUERY_CHUNK: a (256, 600) block stays in a core's cache. Each
        # cell's column is solved alone, so the mean is the same bits as one block and the
        # 1-sigma the same to ~1e-12 (the order of the sums of squares); any thread count.
        for s in range(0, q_idx.size, QUERY_CHUNK):
            rows = q_idx[s : s + QUERY_CHUNK]
            Ks = matrix(xq[rows], Xd, amp)
            mu[s : s + rows.size] = Ks @ alpha  # line 4
            if return_std:
                V = solve_lower(L, Ks.T)  # line 5: v = L^-1 k*, in Ks's memory
                var_s = np.maximum(scale * prior_var - np.einsum("ij,ij->j", V, V), 0.0)
                if W is not None:  # R&W Eq 2.42: the mean coefficients' uncertainty
                    R = basis[1][rows] - (W.T @ V).T
                    var_s += np.einsum("qi,ij,qj->q", R, basis[2], R)
                var[s : s + rows.size] = var_s  # line 6
        return q_idx, w, mu, var, int(d_idx.size), capped, jitter, amp

    mean = np.zeros(xq.shape[0])
    second = np.zeros(xq.shape[0]) if return_std else None
    stats = {"tiles": 0, "max_points_used": 0, "tiles_capped": 0, "max_jitter": 0.0}
    amps = []
    # One BLAS thread per tile and tiles in parallel threads: OpenBLAS's own threading is
    # ~20x slower than serial on these small matrices here (Cholesky of 600: 110 vs 4.6 ms).
    # Results are accumulated in tile order, so they do not depend on the thread count.
    with threadpool_limits(1), ThreadPoolExecutor(max_workers=workers) as pool:
        for out in pool.map(one_tile, tiles):
            if out is None:
                continue
            q_idx, w, mu, var, n_used, capped, jitter, amp = out
            if amp is not None:
                amps.append(amp)
            stats["tiles"] += 1
            stats["max_points_used"] = max(stats["max_points_used"], n_used)
            stats["tiles_capped"] += int(capped)
            stats["max_jitter"] = max(stats["max_jitter"], jitter)
            mean[q_idx] += w * mu
            if return_std:
                second[q_idx] += w * (var + mu * mu)
    if amps:
        stats["amplitudes"] = np.percentile(amps, [5, 50, 95]).tolist()
    std = np.sqrt(np.maximum(second - mean * mean, 0.0)) if return_std else None
    return mean, std, stats


def warn_long_scale(long_part: Any, halo: float) -> str:
    """Warn that tiles cannot hold ``long_part`` (see :func:`long_scale_part`); the words
    are returned too, for the product's provenance (``tiling_warning``)."""
    text = (
        f"the tiled GP sees data only within {halo:.0f} m of a tile, but the kernel part "
        f"{long_part!r} carries a large variance at a longer scale and the survey leaves "
        "gaps wider than that: far from data the map will revert to the prior mean. Use a "
        "prior mean that holds the long scale (a satellite DEM: glacimap reconstruct "
        "--prior), or in Python method='exact' or TileSpec(halo=...)."
    )
    warnings.warn(text, TilingWarning, stacklevel=3)
    return text
