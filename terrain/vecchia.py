"""Vecchia approximation of the GP log marginal likelihood (Eq 9) with its exact gradient.

Eq 9 needs the Cholesky factor of an (n, n) matrix: O(n^3), 1 s for n = 2,000 on this
machine, and an optimizer needs ~50 of them per kernel. Vecchia (1988) writes the joint
density as a product of conditionals and conditions each sample only on ``m`` *earlier*
samples near it, in a fixed (seeded, random) order::

    log p(y) ~= log p(y_1..y_m) + sum_{i > m} log p(y_i | y_N(i)),   |N(i)| = m

Each conditional is a Gaussian with ``mu_i = c_i^T C_N^-1 y_N`` and
``s_i^2 = c_ii - c_i^T C_N^-1 c_i`` (C_N: covariance of the neighbours, noise included; c_i:
their covariance with sample i), so the whole likelihood costs O(n m^3) in batched small
solves, and its gradient follows from ``d mu`` and ``d s^2`` (below) with no approximation
beyond the conditioning sets. With random ordering the late samples condition on close
neighbours (the short scale, the nugget) and the early ones on far ones (the long scale);
Guinness (2018, Technometrics 60:415) and Katzfuss & Guinness (2021, Stat. Sci. 36:124)
show m = 20-30 nearest earlier neighbours give parameter estimates indistinguishable from
exact ones. Ours are checked against the exact Eq 9 in ``tests/test_vecchia.py``.

Conditioning sets (any set of earlier samples is a valid Vecchia set): the kernel search
uses doubling blocks (:func:`block_sets`: positions [b, 2b) condition on their m nearest
among [0, b)). That is not Eq 9 to a few nats on dense data (240-360 nats below it on real
DEMs); each sample's m nearest *earlier* samples (:func:`nearest_earlier`) are within 1-4
nats at m = 25 but chose worse maps (docs/terrain.md "The kernel search's likelihood is
not Eq 9 to a few nats").
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .compiled import compiled
from .errors import NumericalError, bad_input
from .likelihood import gaussian_lml
from .vecchia_compiled import build_conditionals, fused_parts

__all__ = [
    "VecchiaPlan",
    "block_sets",
    "nearest_earlier",
    "nearest_neighbour_predict",
    "vecchia_lml",
]

_LOG_2PI = np.log(2.0 * np.pi)


@dataclass(frozen=True)
class VecchiaPlan:
    """Ordering and conditioning sets of a Vecchia likelihood.

    Attributes
    ----------
    order : ndarray of shape (n,)
        Sample index at each position of the ordering.
    neighbours : ndarray of shape (n - m, m)
        For positions m..n-1, the *sample indices* of their conditioning sets.
    m : int
        Conditioning-set size; positions 0..m-1 form one exact joint block.
    """

    order: np.ndarray
    neighbours: np.ndarray
    m: int
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def build(
        cls, X: np.ndarray, m: int, rng: np.random.Generator, sets: str = "blocks"
    ) -> VecchiaPlan:
        """Random order (from ``rng``) and conditioning sets of size m: ``"blocks"`` (the
        kernel search's, :func:`block_sets`) or ``"nearest"`` (:func:`nearest_earlier`)."""
        if sets not in ("blocks", "nearest"):
            raise bad_input("sets", sets, '"blocks" or "nearest"', 'sets="blocks"')
        n = X.shape[0]
        m = int(min(m, max(n - 1, 1)))
        order = rng.permutation(n)
        find = block_sets if sets == "blocks" else nearest_earlier
        nbr = find(X[order], m)
        return cls(order=order, neighbours=order[nbr], m=m, _cache={})

    def pair_sq(self, X: np.ndarray, start: int, batch: int) -> tuple[np.ndarray, np.ndarray]:
        """Squared coordinate differences (b, P, 2) and their sum over the axes (b, P) of
        the conditioning sets at tail positions [start, start + batch), each set ordered
        neighbours first, then the sample; P = (m+1)(m+2)/2 pairs of the upper triangle
        (:func:`_upper`): the blocks are symmetric, so the kernel is evaluated once per pair.
        Cached per (X, batch): an optimizer evaluates the same sets many times."""
        key = (id(X), X.shape, start, batch)
        if key not in self._cache:
            idx = self.order[self.m :][start : start + batch]
            sets = np.concatenate([self.neighbours[start : start + batch], idx[:, None]], 1)
            P = X[sets]
            iu, ju = _upper(self.m + 1)
            D = P[:, iu, :] - P[:, ju, :]
            sq = D * D
            self._cache[key] = (sq, sq.sum(-1))
        return self._cache[key]


def block_sets(Xo: np.ndarray, m: int) -> np.ndarray:
    """Conditioning sets by doubling blocks: positions [b, 2b) of ``Xo`` (n, 2) take their m
    nearest among positions [0, b), for b = m, 2m, 4m... Shape (n - m, m), positions.

    A valid Vecchia set (any earlier samples are), but not the nearest earlier ones: the
    second half of the order conditions on the first half alone, ~1.4x farther away. On
    dense real-DEM fit subsets this likelihood lies 240-360 nats below the exact Eq 9 and
    moves by 60-90 nats with the ordering; it is the kernel search's evidence all the same,
    because the nearest earlier sets (within 1-4 nats of Eq 9) fitted nuggets ~10x larger
    and picked smoother kernels, and the maps read worse on the real-DEM benchmark
    (docs/terrain.md "The kernel search's likelihood is not Eq 9 to a few nats").
    """
    n = Xo.shape[0]
    rows = []
    b = m
    while b < n:
        hi = min(2 * b, n)
        _, nn = cKDTree(Xo[:b]).query(Xo[b:hi], k=m)
        rows.append(np.asarray(nn).reshape(hi - b, m))
        b = hi
    return np.vstack(rows) if rows else np.empty((0, m), dtype=int)


def nearest_earlier(Xo: np.ndarray, m: int) -> np.ndarray:
    """Positions of the m nearest earlier points of each position m..n-1 of ``Xo`` (n, 2),
    nearest first: shape (n - m, m).

    With these sets m = 25 is within 1-4 nats of the exact Eq 9 for Matérn forms on
    2,000 real-DEM samples, whatever the ordering (:func:`block_sets`: 240-360 below).

    Early positions, with few earlier points, are solved by brute force; the rest take
    their K = 8m nearest points of the whole set and keep the earlier ones, falling back to
    brute force where fewer than m of those are earlier.
    """
    n = Xo.shape[0]
    out = np.empty((max(n - m, 0), m), dtype=np.int64)
    if n <= m:
        return out
    k = int(min(n, 8 * m))
    # Position i expects k * i / n earlier points among its k nearest: brute force below
    # the position where that is 2m.
    head = int(min(n, max(m + 1, np.ceil(2.0 * m * n / k))))

    def brute(i: int) -> np.ndarray:
        d2 = np.sum((Xo[:i] - Xo[i]) ** 2, axis=1)
        idx = np.argpartition(d2, m - 1)[:m] if i > m else np.arange(i)
        return idx[np.lexsort((idx, d2[idx]))]

    for i in range(m, head):
        out[i - m] = brute(i)
    if head < n:
        _, nn = cKDTree(Xo).query(Xo[head:], k=k)
        nn = np.asarray(nn).reshape(n - head, k)
        pos = np.arange(head, n)[:, None]
        earlier = nn < pos
        enough = earlier.sum(axis=1) >= m
        # stable sort keeps the distance order: earlier points first, nearest first
        first = np.argsort(~earlier, axis=1, kind="stable")[:, :m]
        rows = np.take_along_axis(nn, first, axis=1)
        out[head - m :][enough] = rows[enough]
        for j in np.flatnonzero(~enough):
            out[head - m + j] = brute(head + j)
    return out


def _upper(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the upper triangle (diagonal included) of a k x k block."""
    return np.triu_indices(k)


def _pair_tensors(kernel, sq: np.ndarray, gradients: bool = True):
    """Covariances of point pairs and their log-parameter derivatives.

    ``sq`` (..., d) holds the squared coordinate differences of the pairs per axis (cached
    in the plan: they do not change with the hyperparameters), or a tuple (per-axis,
    summed). Returns C (...) and a list of dC (...), one per kernel theta (empty unless
    ``gradients``), in the layout of ``sq`` (full blocks or packed upper triangles).
    """
    parts = getattr(kernel, "parts", (kernel,))
    if isinstance(sq, tuple):  # (per-axis, summed) from the plan's cache
        sq, total = sq
    else:
        total = sq.sum(-1)  # unscaled squared distances, shared by isotropic parts
    C = None
    grads = []
    for p in parts:
        ls = p.lengths
        d2 = total / (ls[0] * ls[0]) if ls.size == 1 else (sq / (ls * ls)).sum(-1)
        if not gradients:
            Kp = p._rho_overwrite(d2)
            Kp *= p.variance
            C = Kp if C is None else C + Kp
            continue
        rho, g = p._rho_and_dlog(d2)
        Kp = p.variance * rho
        C = Kp if C is None else C + Kp
        grads.append(Kp)  # d/dlog variance
        g *= p.variance
        if ls.size == 1:
            grads.append(g * d2)
        else:
            for axis in range(ls.size):
                grads.append(g * sq[..., axis] / (ls[axis] * ls[axis]))
    return C, grads


def vecchia_lml(
    kernel,
    X: np.ndarray,
    r: np.ndarray,
    noise_var: np.ndarray,
    plan: VecchiaPlan,
    eval_gradient: bool = False,
    nugget: float | None = None,
    batch: int = 4096,
    pool: Executor | None = None,
    parts: int = 1,
) -> float | tuple[float, np.ndarray]:
    """Vecchia log marginal likelihood of residuals ``r`` (Eq 9, approximated).

    Parameters
    ----------
    kernel : Kernel or SumKernel
        Covariance with the hyperparameters to evaluate.
    X : ndarray of shape (n, 2)
        Sample locations, m (centred coordinates are best).
    r : ndarray of shape (n,)
        Samples minus the prior mean, m.
    noise_var : ndarray of shape (n,)
        Per-sample noise variance including any nugget, m^2.
    plan : VecchiaPlan
        Ordering and conditioning sets for these ``X``.
    eval_gradient : bool
        Also return the gradient with respect to the kernel's log-parameters, then
        d / d log(nugget) when ``nugget`` is given (the same layout as
        :func:`terrain.likelihood.gaussian_lml`).
    nugget : float, optional
        The nugget inside ``noise_var``.
    batch : int
        Conditionals evaluated per batch (memory: batch x (m+1)^2 x n_params doubles).
    pool : Executor, optional
        Threads to evaluate the pieces on (numpy's batched solves release the GIL).
    parts : int
        Each batch is cut into this many pieces, summed in order; the value depends on
        ``parts`` (the order of the float sums), not on ``pool``.

    Raises
    ------
    NumericalError
        When a conditional variance is not positive (the optimizer treats it as -inf).
    """
    m = plan.m
    head = plan.order[:m]
    # The first m samples: one exact joint Gaussian (R&W Alg. 2.1 line 8 on m points).
    out = gaussian_lml(kernel, X[head], r[head], noise_var[head], eval_gradient, True, nugget)
    lml, grad = out if eval_gradient else (out, None)
    tail = plan.order[m:]
    n_grad = 0 if grad is None else grad.size
    ranges = []  # (start, stop) of the tail positions: batches, each cut in `parts`
    for a in range(0, tail.size, batch):
        cuts = np.linspace(a, min(a + batch, tail.size), parts + 1).astype(int)
        pieces = zip(cuts[:-1], cuts[1:], strict=True)
        ranges += [(int(lo), int(hi)) for lo, hi in pieces if hi > lo]

    def rows(ab: tuple[int, int]) -> tuple[float, np.ndarray]:
        return _rows(kernel, X, r, noise_var, plan, ab, eval_gradient, nugget, n_grad)

    # The same ranges and the same order of the sums with or without threads: same bits.
    outs = list(pool.map(rows, ranges)) if pool is not None else [rows(ab) for ab in ranges]
    for part_lml, part_grad in outs:
        lml += part_lml
        if eval_gradient:
            grad += part_grad
    return (lml, np.asarray(grad)) if eval_gradient else lml


def nearest_neighbour_predict(
    kernel,
    X: np.ndarray,
    r: np.ndarray,
    noise_var: np.ndarray,
    Xq: np.ndarray,
    m: int = 20,
    batch: int = 4096,
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior mean and variance of the latent surface at ``Xq`` from each query's ``m``
    nearest samples (a nearest-neighbour GP: the Vecchia conditional of a new point).

    Parameters
    ----------
    X, r, noise_var : ndarrays of shape (n, 2), (n,), (n,)
        Samples, residuals (m) and their noise variance including the nugget (m^2).
    Xq : ndarray of shape (q, 2)
        Query points, same frame as ``X``.

    Returns
    -------
    mean, var : ndarrays of shape (q,)
        R&W Alg. 2.1 lines 4-6 on each query's neighbourhood (var without noise), m, m^2.
    """
    m = int(min(m, X.shape[0]))
    _, nb = cKDTree(X).query(Xq, k=m)
    nb = np.asarray(nb).reshape(len(Xq), m)
    mean = np.empty(len(Xq))
    var = np.empty(len(Xq))
    prior = float(kernel.diag(Xq[:1])[0])
    for s in range(0, len(Xq), batch):
        sl = slice(s, s + batch)
        P = np.concatenate([X[nb[sl]], Xq[sl, None, :]], axis=1)  # (b, m + 1, 2)
        D = P[:, :, None, :] - P[:, None, :, :]
        C, _ = _pair_tensors(kernel, D * D, gradients=False)
        Cn, c = C[:, :m, :m], C[:, :m, m]
        Cn[:, np.arange(m), np.arange(m)] += noise_var[nb[sl]]
        sol = np.linalg.solve(Cn, np.stack([r[nb[sl]], c], axis=-1))
        mean[sl] = np.einsum("bj,bj->b", c, sol[..., 0])
        var[sl] = np.maximum(prior - np.einsum("bj,bj->b", c, sol[..., 1]), 0.0)
    return mean, var


def _rows(
    kernel, X, r, noise_var, plan, ab, eval_gradient, nugget, n_grad
) -> tuple[float, np.ndarray]:
    """The conditionals at tail positions ``ab = (start, stop)``: their log-density sum
    and its gradient (length ``n_grad``; zeros without ``eval_gradient``)."""
    m = plan.m
    iu, ju = _upper(m + 1)
    off = iu != ju
    lml = 0.0
    grad = np.zeros(n_grad)
    a, b = ab
    idx = plan.order[m:][a:b]
    nb = plan.neighbours[a:b]
    nv = noise_var[np.concatenate([nb, idx[:, None]], axis=1)]
    parts = fused_parts(kernel)
    loop = None if parts is None else compiled("vecchia.conditionals", build_conditionals)
    if loop is not None:
        total = plan.pair_sq(X, a, b - a)[1]
        nug = -1.0 if nugget is None or not eval_gradient else float(nugget)
        status, part = loop(total, *parts, nv, r[nb], r[idx], nug, eval_gradient, iu, ju, grad)
        if status == 1:
            raise NumericalError("Vecchia neighbour covariance is singular")
        if status == 2:
            raise NumericalError("a Vecchia conditional variance is not positive")
        return part - 0.5 * idx.size * _LOG_2PI, grad
    Cp, dCs = _pair_tensors(kernel, plan.pair_sq(X, a, b - a), eval_gradient)
    C = np.empty((idx.size, m + 1, m + 1))
    C[:, iu, ju] = Cp
    C[:, ju, iu] = Cp
    diag = np.arange(m + 1)
    C[:, diag, diag] += nv
    Cn, c, cii = C[:, :m, :m], C[:, :m, m], C[:, m, m]
    yN, yi = r[nb], r[idx]
    try:
        sol = np.linalg.solve(Cn, np.stack([yN, c], axis=-1))  # (b, m, 2)
    except np.linalg.LinAlgError as exc:
        raise NumericalError("Vecchia neighbour covariance is singular") from exc
    alpha, bvec = sol[..., 0], sol[..., 1]
    mu = np.einsum("bj,bj->b", c, alpha)
    s2 = cii - np.einsum("bj,bj->b", c, bvec)
    if not np.all(s2 > 0):
        raise NumericalError("a Vecchia conditional variance is not positive")
    e = yi - mu
    lml += float(np.sum(-0.5 * e * e / s2 - 0.5 * np.log(s2)) - 0.5 * idx.size * _LOG_2PI)
    if not eval_gradient:
        return lml, grad
    # d mu = dc^T alpha - b^T dC_N alpha;  d s2 = dc_ii - 2 dc^T b + b^T dC_N b, so
    # d lml = sum_b w_mu d mu + w_s2 d s2 is linear in dC: one weight tensor W per batch
    # and d lml / d theta_j = <dC_j, W> (one dot product per hyperparameter).
    w_mu, w_s2 = e / s2, 0.5 * (e * e / s2 - 1.0) / s2
    W = np.zeros_like(C)
    W[:, :m, :m] = bvec[:, :, None] * (w_s2[:, None] * bvec - w_mu[:, None] * alpha)[:, None, :]
    W[:, :m, m] = w_mu[:, None] * alpha - 2.0 * w_s2[:, None] * bvec
    W[:, m, m] = w_s2
    Wp = W[:, iu, ju]  # packed: an off-diagonal pair stands for both (k, l) and (l, k)
    Wp[:, off] += W[:, ju[off], iu[off]]
    for j, dC in enumerate(dCs):
        grad[j] += float(np.vdot(dC, Wp))
    if nugget is not None:  # dC = nugget * I on the diagonal, zero off it
        dmu = -nugget * np.einsum("bj,bj->b", bvec, alpha)
        ds2 = nugget * (1.0 + np.einsum("bj,bj->b", bvec, bvec))
        grad[len(dCs)] += float(np.sum(w_mu * dmu + w_s2 * ds2))
    return lml, grad
