"""Peer gridding methods for the real-terrain benchmark, each on the same samples and cells.

Every function takes samples (``terrain.ElevationSamples``) and query cells ``q`` (m, 2) and
returns ``(mean, std_or_None, info)``: ``std`` when the method states an uncertainty,
``info`` a JSON-safe dict of what it chose. Coordinates are centred on the samples' mean
before any peer sees them (UTM eastings/northings are ~1e6 m: conditioning).
"""

from __future__ import annotations

import time

import numpy as np


def _centred(samples, q):
    off = samples.xy.mean(axis=0)
    return samples.xy - off, q - off


def rbf_tps(samples, q, neighbors: int = 64, smoothing: float = 0.0):
    """scipy ``RBFInterpolator``: thin-plate spline on the ``neighbors`` nearest samples."""
    from scipy.interpolate import RBFInterpolator

    xy, qc = _centred(samples, q)
    rbf = RBFInterpolator(
        xy, samples.z, kernel="thin_plate_spline", neighbors=neighbors, smoothing=smoothing
    )
    return rbf(qc), None, {"neighbors": neighbors, "smoothing": smoothing}


def verde_knn(samples, q):
    """``verde.KNeighbors()`` with its defaults (k=1 in verde 1.9, mean reduction)."""
    import verde as vd

    xy, qc = _centred(samples, q)
    knn = vd.KNeighbors().fit((xy[:, 0], xy[:, 1]), samples.z)
    return knn.predict((qc[:, 0], qc[:, 1])), None, {"k": knn.k}


def spline_blocks(samples, spacing: float = 4.0) -> int:
    """How many data points ``verde.BlockReduce(np.median, spacing)`` leaves (cheap)."""
    import verde as vd

    xy, _ = _centred(samples, samples.xy[:1])
    coords, _ = vd.BlockReduce(np.median, spacing=spacing).filter((xy[:, 0], xy[:, 1]), samples.z)
    return int(coords[0].size)


def verde_spline(samples, q, spacing: float = 4.0):
    """``verde.BlockReduce(np.median, spacing)`` then ``verde.Spline()`` (defaults: exact
    biharmonic spline, one force per block, solved by dense least squares: O(m^2) memory,
    O(m^3) time in the number of blocks m)."""
    import verde as vd

    xy, qc = _centred(samples, q)
    t0 = time.perf_counter()
    coords, z = vd.BlockReduce(np.median, spacing=spacing).filter((xy[:, 0], xy[:, 1]), samples.z)
    t1 = time.perf_counter()
    spline = vd.Spline().fit(coords, z)
    t2 = time.perf_counter()
    pred = spline.predict((qc[:, 0], qc[:, 1]))
    t3 = time.perf_counter()
    info = {
        "block_spacing_m": spacing,
        "blocks": int(coords[0].size),
        "reduce_s": t1 - t0,
        "fit_s": t2 - t1,
        "predict_s": t3 - t2,
    }
    return pred, None, info


def pykrige_ok(
    samples,
    q,
    max_samples: int = 3000,
    variogram: str = "spherical",
    n_closest: int = 64,
    seed: int = 0,
):
    """PyKrige ordinary kriging: variogram fitted (``variogram``, 30 lags) on at most
    ``max_samples`` samples (a seeded subsample beyond that), executed on the cells with a
    moving window of ``n_closest`` points (C backend). The kriging variance gives the std."""
    from pykrige.ok import OrdinaryKriging

    xy, qc = _centred(samples, q)
    z = samples.z
    used = samples.n
    if samples.n > max_samples:
        pick = np.sort(np.random.default_rng(seed).choice(samples.n, max_samples, replace=False))
        xy, z, used = xy[pick], z[pick], max_samples
    t0 = time.perf_counter()
    ok = OrdinaryKriging(xy[:, 0], xy[:, 1], z, variogram_model=variogram, nlags=30)
    t1 = time.perf_counter()
    try:
        backend = "C"
        mean, var = ok.execute(
            "points", qc[:, 0], qc[:, 1], backend=backend, n_closest_points=n_closest
        )
    except (ImportError, ValueError):  # no compiled extension: the pure-Python loop
        backend = "loop"
        mean, var = ok.execute(
            "points", qc[:, 0], qc[:, 1], backend=backend, n_closest_points=n_closest
        )
    t2 = time.perf_counter()
    mean = np.asarray(np.ma.filled(mean, np.nan), float)
    std = np.sqrt(np.maximum(np.asarray(np.ma.filled(var, np.nan), float), 0.0))
    info = {
        "variogram_model": variogram,
        "variogram_parameters": [float(v) for v in ok.variogram_model_parameters],
        "samples_used": used,
        "subsampled": samples.n > max_samples,
        "n_closest_points": n_closest,
        "backend": backend,
        "fit_s": t1 - t0,
        "predict_s": t2 - t1,
    }
    return mean, std, info
