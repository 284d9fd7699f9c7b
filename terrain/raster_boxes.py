"""Boxes between CRSs for :class:`~terrain.raster_mean.RasterMean`: a validated
``(west, south, east, north)``, its densified edge ring, unions and containment, a box
transformed between CRSs, and the map lattice a DEM is reprojected onto."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from pyproj import CRS, Transformer

from .errors import bad_input
from .raster_source import RasterSource

__all__ = ["bbox", "box", "fmt_box", "inside", "lattice", "ring", "transform_box", "union"]

DENSIFY = 21  # points per side when transforming a box between CRSs


def box(bounds: Any, field: str = "bounds") -> tuple[float, float, float, float]:
    try:
        w, s, e, n = (float(b) for b in bounds)
    except (TypeError, ValueError) as exc:
        raise bad_input(field, bounds, "(west, south, east, north) in metres", "") from exc
    if not (np.all(np.isfinite([w, s, e, n])) and e >= w and n >= s):
        raise bad_input(field, bounds, "finite (west, south, east, north), east >= west", "")
    return (w, s, e, n)


def ring(bounds: tuple[float, float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Points along the edges of ``bounds``, for transforming a box between CRSs."""
    w, s, e, n = bounds
    t = np.linspace(0.0, 1.0, DENSIFY)
    xs = np.concatenate([w + (e - w) * t, np.full_like(t, e), e - (e - w) * t, np.full_like(t, w)])
    ys = np.concatenate([np.full_like(t, s), s + (n - s) * t, np.full_like(t, n), n - (n - s) * t])
    return xs, ys


def fmt_box(b: tuple[float, ...]) -> str:
    return "(" + ", ".join(f"{v:.6g}" if abs(v) < 1e3 else f"{v:.1f}" for v in b) + ")"


def bbox(xy: np.ndarray) -> tuple[float, float, float, float]:
    return (xy[:, 0].min(), xy[:, 1].min(), xy[:, 0].max(), xy[:, 1].max())


def union(a: tuple, b: tuple) -> tuple[float, float, float, float]:
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


def inside(a: tuple, b: tuple) -> bool:
    return a[0] >= b[0] and a[1] >= b[1] and a[2] <= b[2] and a[3] <= b[3]


def transform_box(tr: Transformer, bounds: tuple) -> tuple[float, float, float, float]:
    xs, ys = tr.transform(*ring(bounds))
    ok = np.isfinite(xs) & np.isfinite(ys)
    return (float(xs[ok].min()), float(ys[ok].min()), float(xs[ok].max()), float(ys[ok].max()))


def lattice(
    src: RasterSource, crs: CRS, to_src: Transformer, to_map: Transformer, requested: tuple
) -> tuple[float, float, float, float]:
    """Origin and steps ``(ox, oy, rx, ry)`` (m) of the map lattice.

    In the source's own CRS, the source's cells (so the bound raster is the source itself and
    queries are one bilinear step on it); otherwise square cells of one source cell in map
    metres at the centre of ``requested`` (the smaller side), anchored at (0, 0).
    """
    t = src.transform
    if src.crs.equals(crs):
        return (t.c, t.f, abs(t.a), abs(t.e))
    cx, cy = to_src.transform((requested[0] + requested[2]) / 2, (requested[1] + requested[3]) / 2)
    dx, dy = src.resolution
    xs, ys = to_map.transform([cx, cx + dx, cx], [cy, cy, cy + dy])
    res = min(math.hypot(xs[1] - xs[0], ys[1] - ys[0]), math.hypot(xs[2] - xs[0], ys[2] - ys[0]))
    if not (np.isfinite(res) and res > 0):
        raise bad_input("source.transform", (dx, dy), "a positive cell size", "check the DEM")
    return (0.0, 0.0, float(res), float(res))
