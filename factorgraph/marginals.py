"""Every landmark's 3x3 marginal covariance at the final estimate, in seconds, exactly.

Method (Schur complement through each landmark's own information block)
-----------------------------------------------------------------------
Linearize the whole graph at the final estimate (robust kernels reweighted there, as
``gtsam.Marginals`` does). Order the variables as landmarks ``l`` and the pose system ``p``
(per keyframe: Pose3 tangent [rotation, translation], with the bias model the GPS bias, with
the drift model the odometry drift state [scale, heading rate]).
The information matrix is ``[[A, B], [B^T, H]]`` with ``A`` block-diagonal (one 3x3 per
landmark). Then, exactly,

    Sigma_pp = S^-1,  S = H - B^T A^-1 B           (the reduced camera system)
    Sigma_l  = A_l^-1 + A_l^-1 B_l Sigma_pp B_l^T A_l^-1   (Woodbury on the joint)

and ``B_l`` touches only the keyframes that saw landmark ``l``. A landmark is seen from a
window of at most ``W`` consecutive keyframes, so ``S`` is block-banded with bandwidth ``W``
(consecutive in the elimination order: where adjacent swaths share landmarks the keyframes are
renumbered by reverse Cuthill-McKee, so that ``W`` stays a few local windows, not a leg);
grouping keyframes into super-blocks of ``W`` makes it block-tridiagonal, whose inverse
restricted to the band follows from one forward elimination and one backward (RTS-like)
sweep (Rybicki & Hummer; the selected inverse). Cost ``O(K W^2 d^3)`` instead of one Bayes-tree
shortcut per landmark. ``tests/test_localize.py`` checks it against ``gtsam.Marginals``.

The shared GPS offset: the mean world-translation error of all keyframes,
``delta = (1/K) sum_k R_k dt_k``, is the rigid shift every landmark inherits from the
unobservable mean GPS bias. Its covariance ``J S^-1 J^T`` and its cross-covariance with each
landmark give the relative covariance ``cov(e_l - delta)`` used by the 0.5 m rule.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

__all__ = ["LandmarkMarginals", "landmark_marginals"]


@dataclass
class LandmarkMarginals:
    """Output of :func:`landmark_marginals` (world ENU frame, m^2)."""

    landmark_cov: np.ndarray  # (L, 3, 3) full marginal
    landmark_cov_relative: np.ndarray  # (L, 3, 3) with the shared offset removed
    shared_cov: np.ndarray  # (3, 3) covariance of the map-wide rigid offset
    pose_cov_xyz: np.ndarray  # (K, 3, 3) keyframe position covariance, world frame
    bandwidth: int  # W, the band of the pose system in the (renumbered) elimination order


def _layout(bias_model: bool, drift_model: bool) -> dict[str, tuple[int, int]]:
    """Per-keyframe state layout: symbol -> (offset, dimension) inside a keyframe's block."""
    out, d = {"x": (0, 6)}, 6
    if bias_model:
        out["b"], d = (d, 3), d + 3
    if drift_model:
        out["d"] = (d, 2)
    return out


def _factor_blocks(graph, values, lm_index: dict[int, int], layout: dict[str, tuple[int, int]]):
    """Split the linearized graph into projection factors and pose-system factors."""
    import gtsam

    gfg = graph.linearize(values)
    sym = gtsam.Symbol
    proj_x, proj_l, proj_k, proj_j = [], [], [], []
    other: list[tuple[np.ndarray, list[tuple[int, int, int]]]] = []
    lm_prior: list[tuple[int, np.ndarray]] = []
    for i in range(gfg.size()):
        f = gfg.at(i)
        if f is None:
            continue
        A, _ = f.jacobian()
        keys = list(f.keys())
        cols, c0 = [], 0
        lm_col = None
        for key in keys:
            s = sym(key)
            ch, idx = chr(s.chr()), int(s.index())
            if ch == "l":
                lm_col = (c0, lm_index[idx])
                c0 += 3
            else:  # a per-keyframe state: pose, GPS bias or odometry drift
                off, dim = layout[ch]
                cols.append((c0, idx, off, dim))
                c0 += dim
        if lm_col is not None and not cols:  # landmark prior
            Al_only = A[:, lm_col[0] : lm_col[0] + 3]
            lm_prior.append((lm_col[1], Al_only.T @ Al_only))
        elif lm_col is not None:
            ((cx, k, _, _),) = cols
            proj_x.append(A[:, cx : cx + 6])
            proj_l.append(A[:, lm_col[0] : lm_col[0] + 3])
            proj_k.append(k)
            proj_j.append(lm_col[1])
        else:
            other.append((A, cols))
    return (
        np.array(proj_x).reshape(-1, 2, 6),
        np.array(proj_l).reshape(-1, 2, 3),
        np.array(proj_k, int),
        np.array(proj_j, int),
        other,
        lm_prior,
    )


def _pairs(starts: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All ordered pairs (i, j) of observation rows that belong to the same landmark."""
    if counts.size == 0 or counts.sum() == 0:
        return np.zeros(0, int), np.zeros(0, int)
    runs = list(zip(starts, counts, strict=True))
    ii = np.concatenate([np.repeat(np.arange(s, s + c), c) for s, c in runs])
    jj = np.concatenate([np.tile(np.arange(s, s + c), c) for s, c in runs])
    return ii, jj


def _keyframe_order(n_keyframes: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Position of each keyframe in the elimination order: reverse Cuthill-McKee on the
    keyframes' coupling graph (edges ``a[i] - b[i]``) where it narrows the band, else the
    time order.

    A landmark seen from two adjacent swaths couples keyframes a whole leg apart in time, and
    the band (the landmark's keyframe span ``W``) then grows to a leg: the cost ``O(K W^2 d^3)``
    with it (a two-leg 391-keyframe traverse, legs 30 m apart: 23 s). Ordered by RCM the
    swaths interleave and the band is a few local windows wide. Only the order changes; the
    marginals are the same to rounding.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    time_order = np.arange(n_keyframes)
    if a.size == 0 or n_keyframes < 3:
        return time_order
    adj = coo_matrix((np.ones(a.size), (a, b)), shape=(n_keyframes, n_keyframes)).tocsr()
    perm = np.asarray(reverse_cuthill_mckee(adj + adj.T, symmetric_mode=True))
    pos = np.empty(n_keyframes, int)
    pos[perm] = time_order
    if np.abs(pos[a] - pos[b]).max() < np.abs(a - b).max():
        return pos
    return time_order


def _block_tridiag_inverse(D: list[np.ndarray], E: list[np.ndarray]):
    """Diagonal and first off-diagonal blocks of the inverse of an SPD block-tridiagonal
    matrix (diagonal blocks ``D``, super-diagonal ``E``), plus the factors for solves."""
    n = len(D)
    G = [None] * n
    G[0] = cho_factor(D[0])
    for i in range(1, n):
        Gi = D[i] - E[i - 1].T @ cho_solve(G[i - 1], E[i - 1])
        G[i] = cho_factor(Gi)
    S_diag = [None] * n
    S_off = [None] * (n - 1)
    S_diag[-1] = cho_solve(G[-1], np.eye(D[-1].shape[0]))
    for i in range(n - 2, -1, -1):
        F = cho_solve(G[i], E[i])
        S_off[i] = -F @ S_diag[i + 1]
        Gi_inv = cho_solve(G[i], np.eye(D[i].shape[0]))
        S_diag[i] = Gi_inv + F @ S_diag[i + 1] @ F.T
    return S_diag, S_off, G


def _block_tridiag_solve(G, E, rhs: list[np.ndarray]) -> list[np.ndarray]:
    """Solve ``S x = rhs`` with the forward factors ``G`` of :func:`_block_tridiag_inverse`."""
    n = len(G)
    y = [None] * n
    y[0] = rhs[0]
    for i in range(1, n):
        y[i] = rhs[i] - E[i - 1].T @ cho_solve(G[i - 1], y[i - 1])
    x = [None] * n
    x[-1] = cho_solve(G[-1], y[-1])
    for i in range(n - 2, -1, -1):
        x[i] = cho_solve(G[i], y[i] - E[i] @ x[i + 1])
    return x


def landmark_marginals(
    graph,
    values,
    n_keyframes: int,
    landmark_ids,
    bias_model: bool,
    drift_model: bool = False,
    reorder: bool = True,
):
    """Marginal covariances of every landmark (and keyframe position) at ``values``.

    Parameters
    ----------
    graph : gtsam.NonlinearFactorGraph
        The full graph (``ISAM2.getFactorsUnsafe()``).
    values : gtsam.Values
        The final estimate.
    n_keyframes : int
        Keyframes ``x0..x{K-1}`` (and biases ``b0..`` when ``bias_model``).
    landmark_ids : sequence of int
        Landmark indices ``l{id}`` present in the graph, in the output order.
    bias_model : bool
        Whether GPS bias states ``b{k}`` exist.
    drift_model : bool
        Whether odometry drift states ``d{k}`` (Point2) exist.
    reorder : bool
        Renumber the keyframes to a narrower band where one exists (:func:`_keyframe_order`);
        ``False`` keeps the time order (the same covariances, slower where swaths share
        landmarks; ``benchmarks/marginals_order.py``).

    Returns
    -------
    LandmarkMarginals
    """
    import gtsam
    from threadpoolctl import threadpool_limits

    layout = _layout(bias_model, drift_model)
    K, d = n_keyframes, sum(dim for _, dim in layout.values())
    ids = list(landmark_ids)
    lm_index = {lid: j for j, lid in enumerate(ids)}
    nL = len(ids)
    Ax, Al, pk, pj, other, lm_prior = _factor_blocks(graph, values, lm_index, layout)
    # Keyframes renumbered to a narrow band (_keyframe_order); pose_xyz is mapped back below.
    order = np.lexsort((pk, pj))
    pk, pj, Al, Ax = pk[order], pj[order], Al[order], Ax[order]
    starts = np.searchsorted(pj, np.arange(nL))
    counts = np.bincount(pj, minlength=nL)
    ii_all, jj_all = _pairs(starts, counts)
    ea, eb = [pk[ii_all]], [pk[jj_all]]
    for _, cols in other:  # a chain through each factor's keyframes
        ks = [k for _, k, _, _ in cols]
        ea.append(np.array(ks[:-1], int))
        eb.append(np.array(ks[1:], int))
    pos = _keyframe_order(K, np.concatenate(ea), np.concatenate(eb)) if reorder else np.arange(K)
    pk = pos[pk]
    other = [(Af, [(c, int(pos[k]), o, n) for c, k, o, n in cols]) for Af, cols in other]
    # Landmark information blocks A_l and couplings B_l (per observation).
    A = np.zeros((nL, 3, 3))
    np.add.at(A, pj, np.einsum("nri,nrj->nij", Al, Al))
    for j, info in lm_prior:
        A[j] += info
    Bo = np.einsum("nri,nrj->nij", Al, Ax)  # (n_obs, 3, 6)
    span = np.zeros(nL, int)
    if pj.size:
        kmin = np.full(nL, K)
        kmax = np.zeros(nL, int)
        np.minimum.at(kmin, pj, pk)
        np.maximum.at(kmax, pj, pk)
        span = kmax - kmin
    W = int(max(1, span.max() if nL else 1))
    for _, cols in other:  # time neighbours (odometry, bias, drift) may sit apart once renumbered
        if len(cols) > 1:
            W = max(W, max(k for _, k, _, _ in cols) - min(k for _, k, _, _ in cols))
    # Pose system H in band storage: band[k, delta] = block (k, k + delta), delta in [0, W].
    band = np.zeros((K, W + 1, d, d))
    for Af, cols in other:
        for ca, ka, oa, na in cols:
            for cb, kb, ob, nb in cols:
                if kb < ka:
                    continue
                blk = Af[:, ca : ca + na].T @ Af[:, cb : cb + nb]
                if kb == ka and ob < oa:
                    continue
                band[ka, kb - ka, oa : oa + na, ob : ob + nb] += blk
                if kb == ka and ob != oa:
                    band[ka, 0, ob : ob + nb, oa : oa + na] += blk.T
    np.add.at(band[:, 0, :6, :6], pk, np.einsum("nri,nrj->nij", Ax, Ax))
    # Schur complement of the landmarks: S = H - sum_l B_l^T A_l^-1 B_l, pairs within a landmark.
    Ainv = np.linalg.inv(A) if nL else A
    order = np.lexsort((pk, pj))
    pk, pj, Bo = pk[order], pj[order], Bo[order]  # pj's runs unchanged: the same pairs
    T = np.einsum("nij,njk->nik", Ainv[pj], Bo)  # A_l^-1 B_i  (n_obs, 3, 6)
    keep = pk[jj_all] >= pk[ii_all]
    ii, jj = ii_all[keep], jj_all[keep]
    blocks = np.einsum("nki,nkj->nij", Bo[ii], T[jj])  # B_i^T A^-1 B_j  (pairs, 6, 6)
    flat = pk[ii] * (W + 1) + (pk[jj] - pk[ii])
    red = np.zeros((K * (W + 1), 6, 6))
    for a in range(6):
        for b in range(6):
            red[:, a, b] = np.bincount(flat, blocks[:, a, b], minlength=K * (W + 1))
    red = red.reshape(K, W + 1, 6, 6)
    band[:, :, :6, :6] -= red
    # Super-blocks of W keyframes: block-tridiagonal.
    nb = -(-K // W)
    size = W * d
    D = [np.zeros((size, size)) for _ in range(nb)]
    E = [np.zeros((size, size)) for _ in range(nb - 1)]
    for k in range(K):
        bi, r = divmod(k, W)
        for delta in range(W + 1):
            k2 = k + delta
            if k2 >= K:
                break
            bj, c = divmod(k2, W)
            blk = band[k, delta]
            if not blk.any():
                continue
            if bj == bi:
                D[bi][r * d : (r + 1) * d, c * d : (c + 1) * d] += blk
                if delta:
                    D[bi][c * d : (c + 1) * d, r * d : (r + 1) * d] += blk.T
            else:
                E[bi][r * d : (r + 1) * d, c * d : (c + 1) * d] += blk
    pad = nb * W - K
    if pad:
        D[-1][size - pad * d :, size - pad * d :] += np.eye(pad * d)
    for Dm in D:
        Dm[:] = 0.5 * (Dm + Dm.T)
    with threadpool_limits(1):
        S_diag, S_off, G = _block_tridiag_inverse(D, E)
        # Shared offset delta = (1/K) sum_k R_k dt_k: J^T as right-hand sides.
        X = gtsam.symbol_shorthand.X
        Rk = np.empty((K, 3, 3))  # in the band's order: Rk[pos[k]] is keyframe k's
        for k in range(K):
            Rk[pos[k]] = values.atPose3(X(k)).rotation().matrix()
        rhs = [np.zeros((size, 3)) for _ in range(nb)]
        for k in range(K):
            bi, r = divmod(k, W)
            rhs[bi][r * d + 3 : r * d + 6] = Rk[k].T / K
        sol = _block_tridiag_solve(G, E, rhs)
    shared = sum(r.T @ s for r, s in zip(rhs, sol, strict=False))
    sol_pose = np.concatenate(sol)[: K * d].reshape(K, d, 3)[:, :6]  # Sigma_{p, delta}

    # Sigma_pp pose blocks in band storage: sig[k, delta] = Sigma(k, k + delta), pose dims.
    sig = np.zeros((K, W + 1, 6, 6))
    for k in range(K):
        bi, r = divmod(k, W)
        for delta in range(min(W, K - 1 - k) + 1):
            bj, c = divmod(k + delta, W)
            src = S_diag[bi] if bj == bi else S_off[bi]
            sig[k, delta] = src[r * d : r * d + 6, c * d : c * d + 6]

    def sigma_block(k1: np.ndarray, k2: np.ndarray) -> np.ndarray:
        """Sigma_pp pose blocks (n, 6, 6) for keyframe pairs with |k1 - k2| <= W."""
        lo, hi = np.minimum(k1, k2), np.maximum(k1, k2)
        out = sig[lo, hi - lo]
        flip = k1 > k2
        out[flip] = np.swapaxes(out[flip], 1, 2)
        return out

    # Sigma_l = A^-1 + sum_{i,j} T_i Sigma_{ki,kj} T_j^T over all ordered pairs.
    Sp = sigma_block(pk[ii_all], pk[jj_all])
    contrib = np.einsum("nia,nab,njb->nij", T[ii_all], Sp, T[jj_all])
    cov = Ainv.copy()
    np.add.at(cov, pj[ii_all], contrib)
    # cross-covariance with the shared offset: cov(l, delta) = -A^-1 sum_i B_i Sigma_{p_i, delta}
    cross = np.zeros((nL, 3, 3))
    np.add.at(cross, pj, -np.einsum("nia,nab->nib", T, sol_pose[pk]))
    rel = cov - cross - np.transpose(cross, (0, 2, 1)) + shared
    pose_diag = sig[:, 0, 3:6, 3:6]
    pose_xyz = np.einsum("kij,kjl,kml->kim", Rk, pose_diag, Rk)[pos]  # back to time order
    sym = lambda c: 0.5 * (c + np.swapaxes(c, -1, -2))  # noqa: E731
    return LandmarkMarginals(sym(cov), sym(rel), sym(shared), sym(pose_xyz), W)
