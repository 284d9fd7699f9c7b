"""Ground features a bicubic site cannot have, for the stress runs of the real-terrain
benchmark (``python benchmarks/real_terrain.py --feature ...``; docs/terrain.md "Ground a
bicubic site cannot have"): a scarp crossed by the tracks or lying between them, a flat lake,
terraces, each added to a site of :mod:`real_dems` and scaled to its relief; and the
scarp's own line, for ``terrain.BreaklineMean``. ``real_dems`` re-exports them.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

#: Ground features a bicubic site cannot have (``add_feature``), each scaled to the site's
#: relief: a scarp as a glacier's ice cliff, a moraine's edge or a fault has; a frozen lake or
#: a flat outwash plain; benches as an open pit or terraced slope has.
FEATURES = ("none", "scarp", "scarp-along", "scarp-end", "lake", "terraces")
#: Where a ``scarp-end`` stops, m east of the site's centre, and the length it dies out over.
SCARP_END_M, SCARP_FADE_M = 150.0, 150.0


def add_feature(truth: xr.DataArray, feature: str) -> xr.DataArray:
    """``truth`` with a sharp ground feature, for the stress runs of the real-terrain benchmark.

    Parameters
    ----------
    truth : xarray.DataArray, dims (y, x)
        A site from :func:`glacier_site`.
    feature : {"none", "scarp", "scarp-along", "scarp-end", "lake", "terraces"}
        ``scarp``: a step of 24 % of the relief (6 m at 25 m), 1.5 m wide (a logistic of that
        scale), up to the north, along a sinuous east-west line through the site's centre
        (40 m amplitude, 565 m wavelength): every north-south track crosses it.
        ``scarp-along``: the same step running north-south, up to the east, lying mostly
        between the tracks. ``scarp-end``: the ``scarp`` dying out inside the site, its
        height falling (half a cosine of the easting) over the 150 m before it stops 150 m
        east of the centre, the ground round its end continuous (a hinge fault; a cliff
        that fades out): the two easternmost tracks do not cross it. ``lake``: the ground
        below its 35th percentile made flat at that level. ``terraces``: benches 10 % of the
        relief high (2.5 m), rising by 30 % of that across each bench and then stepping.

    Returns
    -------
    xarray.DataArray
        The same grid; ``attrs["source"]`` names the feature.
    """
    if feature not in FEATURES:
        raise ValueError(f"feature: expected one of {FEATURES}, got {feature!r}")
    if feature == "none":
        return truth
    z = np.asarray(truth.values, float)
    relief = float(np.ptp(z))
    x = np.asarray(truth.x, float) - float(np.mean(truth.x))
    y = np.asarray(truth.y, float) - float(np.mean(truth.y))
    xx, yy = np.meshgrid(x, y)
    if feature in ("scarp", "scarp-along", "scarp-end"):
        if feature == "scarp-along":
            across = xx - 40.0 * np.sin(yy / 90.0)
        else:
            across = yy - 40.0 * np.sin(xx / 90.0)
        height = 0.24 * relief
        if feature == "scarp-end":
            fade = np.clip((SCARP_END_M - xx) / SCARP_FADE_M, 0.0, 1.0)
            height = height * (0.5 - 0.5 * np.cos(np.pi * fade))
        z = z + height / (1.0 + np.exp(-across / 1.5))
    elif feature == "lake":
        z = np.maximum(z, np.percentile(z, 35.0))
    else:
        step = 0.1 * relief
        u = (z - z.min()) / step
        z = z.min() + (np.floor(u) + 0.3 * (u - np.floor(u))) * step
    out = truth.copy(data=z)
    out.attrs["source"] = f"{truth.attrs.get('source', '')}; feature {feature}"
    return out


def feature_line(truth: xr.DataArray, feature: str) -> np.ndarray | None:
    """The line of a ``scarp``, ``scarp-along`` or ``scarp-end`` (:func:`add_feature`) as
    breakline vertices, shape (k, 2), in the site's CRS, run 200 m beyond the site on either
    side (a ``scarp-end``: from the west only, to where it stops), ordered so the step is up
    to its left (``terrain.BreaklineMean``'s sign); ``None`` for the other features."""
    if feature not in ("scarp", "scarp-along", "scarp-end"):
        return None
    xm, ym = float(np.mean(truth.x)), float(np.mean(truth.y))
    half = 0.5 * float(np.ptp(truth.x.values)) + 200.0
    u = np.linspace(-half, half, int(2 * half) + 1)  # a vertex a metre
    if feature == "scarp-end":
        u = np.append(u[u < SCARP_END_M], SCARP_END_M)
    if feature in ("scarp", "scarp-end"):  # y = 40 sin(x / 90), up to the north: west -> east
        return np.column_stack([xm + u, ym + 40.0 * np.sin(u / 90.0)])
    return np.column_stack([xm + 40.0 * np.sin(-u / 90.0), ym - u])  # up east: north -> south
