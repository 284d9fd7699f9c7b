"""The survey plan: where the rover drives and where its sensor samples (docs/architecture.md §3).

Conventions
-----------
* Coordinates are easting/northing in metres of a projected CRS.
* ``heading_deg`` is the direction of travel of the *first* swath, in degrees clockwise from
  north (0 = north, 90 = east); swaths are driven boustrophedon, so every second swath runs
  at ``heading_deg + 180``.
* The *swath frame* is ``(along, across)`` in metres about ``origin``: ``along`` is measured
  along the heading, unit vector ``u = (sin h, cos h)``; ``across`` along ``v = (-cos h, sin h)``,
  90 degrees counter-clockwise from ``u`` (to the left of the first swath's direction of
  travel). ``(along, across)`` is right-handed like ``(easting, northing)``; at heading 90
  (east) it is ``(easting, northing) - origin``.
* Reference swaths are numbered ``0 .. n_swaths - 1`` in order of increasing ``across``.
* Every waypoint lies on a swath and carries that swath's index. The straight legs *between*
  swaths (turns) and between the pieces of a swath that a hole splits are *transit legs*
  (``transit[j]`` is True for the leg from waypoint ``j`` to ``j + 1``). Samples on a transit
  leg have ``sample_swath == -1``: they are real sensor samples (they count for coverage,
  Eq 11-13) but belong to no reference swath (they are left out of distributedness, Eq 14-16).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pyproj import CRS

from terrain.errors import bad_input
from terrain.grid import as_crs

from .coverage import path_length

__all__ = ["PATTERNS", "SurveyPlan", "heading_vectors"]

PATTERNS = ("lawnmower", "piecewise_continuous")
_TOL = 1e-9  # m: a sample this close to a swath end belongs to the swath


def heading_vectors(heading_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors ``(u, v)`` of the swath frame, each shape (2,), easting/northing.

    ``u`` points along ``heading_deg`` (degrees clockwise from north), ``v`` 90 degrees
    counter-clockwise from ``u``.
    """
    h = np.deg2rad(float(heading_deg))
    return np.array([np.sin(h), np.cos(h)]), np.array([-np.cos(h), np.sin(h)])


def _array(name: str, value: Any, shape: tuple[int | None, ...], dtype: Any) -> np.ndarray:
    arr = np.asarray(value)
    ok = arr.ndim == len(shape) and all(
        s is None or s == a for s, a in zip(shape, arr.shape, strict=True)
    )
    if not ok or (arr.size and not np.all(np.isfinite(arr.astype(float)))):
        want = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ")"
        raise bad_input(
            name,
            getattr(arr, "shape", value),
            f"finite values of shape {want}",
            "pass a numeric array of that shape",
        )
    if np.issubdtype(np.dtype(dtype), np.integer) and arr.size:
        if not np.all(arr.astype(float) == np.round(arr.astype(float))):
            raise bad_input(name, arr[:5], "integer swath indices", "pass ints")
    return np.array(arr, dtype=dtype)  # a private copy: the plan is immutable


@dataclass(frozen=True, eq=False)  # arrays: compare plans field by field, not with ==
class SurveyPlan:
    """A planned survey: the driven path, its sensor samples and its reference swaths.

    Parameters
    ----------
    waypoints : ndarray of shape (k, 2)
        Vertices of the driven polyline in driving order, easting/northing in m.
    swath : ndarray of shape (k,), int
        Reference swath index (0-based) of each waypoint; every waypoint lies on a swath.
    pattern : str
        ``"lawnmower"`` or ``"piecewise_continuous"``.
    params : dict
        JSON-serialisable parameters that made the plan (``n_swaths``, ``heading_deg``,
        ``spacing``, ``seed``, ...).
    samples : ndarray of shape (m, 2)
        Sensor sample locations every ``params["spacing"]`` m along the driven path, m.
    sample_swath : ndarray of shape (m,), int
        Swath index of each sample; ``-1`` on transit legs (see the module notes).
    swath_offsets : ndarray of shape (n_swaths,)
        ``across`` coordinate (m, swath frame) of each reference swath line, increasing.
    heading_deg : float
        Direction of travel of the first swath, degrees clockwise from north.
    origin : tuple of float
        ``(easting, northing)`` of the swath frame's origin, m.
    crs : pyproj.CRS, optional
        Projected CRS of all coordinates.
    transit : ndarray of shape (k - 1,), bool, optional
        True where the leg from waypoint ``j`` to ``j + 1`` is a transit leg; default: legs
        whose two waypoints have different swath indices.
    """

    waypoints: np.ndarray
    swath: np.ndarray
    pattern: str
    params: dict
    samples: np.ndarray
    sample_swath: np.ndarray
    swath_offsets: np.ndarray
    heading_deg: float
    origin: tuple[float, float]
    crs: CRS | None = None
    transit: np.ndarray | None = field(default=None)

    def __post_init__(self) -> None:
        wp = _array("waypoints", self.waypoints, (None, 2), float)
        k = wp.shape[0]
        if k < 1:
            raise bad_input("waypoints", wp.shape, "at least one waypoint", "plan a path")
        sw = _array("swath", self.swath, (k,), np.int64)
        offsets = _array("swath_offsets", self.swath_offsets, (None,), float)
        n = offsets.size
        if n < 1 or np.any(np.diff(offsets) <= 0):
            raise bad_input("swath_offsets", offsets, "n >= 1 increasing offsets, m", "sort them")
        if k and (sw.min() < 0 or sw.max() >= n):
            raise bad_input("swath", sw, f"indices in [0, {n - 1}]", "one per reference swath")
        smp = _array("samples", self.samples, (None, 2), float)
        ssw = _array("sample_swath", self.sample_swath, (smp.shape[0],), np.int64)
        if ssw.size and (ssw.min() < -1 or ssw.max() >= n):
            raise bad_input("sample_swath", ssw, f"indices in [-1, {n - 1}]", "-1 = transit")
        if self.pattern not in PATTERNS:
            raise bad_input("pattern", self.pattern, f"one of {PATTERNS}", "pick a known one")
        if not np.isfinite(self.heading_deg):
            raise bad_input("heading_deg", self.heading_deg, "a finite angle", "e.g. 90.0")
        origin = _array("origin", self.origin, (2,), float)
        try:
            json.dumps(self.params)
        except (TypeError, ValueError) as exc:
            raise bad_input(
                "params", self.params, "a JSON-serialisable dict", "use plain numbers"
            ) from exc
        if self.transit is None:
            tr = sw[1:] != sw[:-1]
        else:
            tr = _array("transit", self.transit, (max(k - 1, 0),), bool)
        for name, value in (
            ("waypoints", wp),
            ("swath", sw),
            ("samples", smp),
            ("sample_swath", ssw),
            ("swath_offsets", offsets),
            ("transit", tr),
        ):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "heading_deg", float(self.heading_deg))
        object.__setattr__(self, "origin", (float(origin[0]), float(origin[1])))
        object.__setattr__(self, "params", dict(self.params))
        if self.crs is not None:
            object.__setattr__(self, "crs", as_crs(self.crs, "crs"))

    @property
    def n_swaths(self) -> int:
        """Number of reference swaths."""
        return int(self.swath_offsets.size)

    @property
    def path_length(self) -> float:
        """Length of the driven path (swaths and transit legs), metres: D_S of D_S / D_T."""
        return path_length(self.waypoints)

    def to_swath_frame(self, xy: np.ndarray) -> np.ndarray:
        """Easting/northing ``xy`` (n, 2) -> ``(along, across)`` (n, 2), metres, about origin."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2) - np.asarray(self.origin)
        u, v = heading_vectors(self.heading_deg)
        return np.column_stack([xy @ u, xy @ v])

    def from_swath_frame(self, along_across: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_swath_frame`: ``(along, across)`` (n, 2) -> easting/northing."""
        aa = np.asarray(along_across, dtype=float).reshape(-1, 2)
        u, v = heading_vectors(self.heading_deg)
        return np.asarray(self.origin) + aa[:, :1] * u + aa[:, 1:] * v

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (lists and plain floats; the CRS as WKT, or None)."""
        return {
            "pattern": self.pattern,
            "heading_deg": self.heading_deg,
            "origin": list(self.origin),
            "crs": None if self.crs is None else self.crs.to_wkt(),
            "params": dict(self.params),
            "path_length_m": self.path_length,
            "swath_offsets": self.swath_offsets.tolist(),
            "waypoints": self.waypoints.tolist(),
            "swath": self.swath.tolist(),
            "transit": self.transit.tolist(),
            "samples": self.samples.tolist(),
            "sample_swath": self.sample_swath.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SurveyPlan:
        """Rebuild a plan written by :meth:`to_dict`."""
        keys = ("waypoints", "swath", "pattern", "params", "samples", "sample_swath")
        keys += ("swath_offsets", "heading_deg", "origin", "crs", "transit")
        kw = {key: data.get(key) for key in keys}
        kw["samples"] = np.asarray(kw["samples"], float).reshape(-1, 2)
        kw["origin"] = tuple(kw["origin"])
        return cls(**kw)


def build_plan(
    waypoints: np.ndarray,
    swath: np.ndarray,
    transit: np.ndarray,
    spacing: float,
    **fields: Any,
) -> SurveyPlan:
    """Sample the polyline every ``spacing`` m and wrap everything in a :class:`SurveyPlan`.

    Samples are at arc lengths ``0, spacing, 2 spacing, ... <= path length`` (m); a sample on
    a transit leg gets swath ``-1`` unless it sits (within 1e-9 m) on the leg's end waypoints.
    ``fields`` are the remaining :class:`SurveyPlan` fields.
    """
    wp = np.asarray(waypoints, float)
    seg = np.diff(wp, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    s = np.arange(0.0, cum[-1] + _TOL, spacing)
    if seg_len.size == 0:
        one = {"samples": wp[:1], "sample_swath": swath[:1], "transit": transit}
        return SurveyPlan(wp, swath, **one, **fields)
    j = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, seg_len.size - 1)
    t = np.clip((s - cum[j]) / np.where(seg_len[j] > 0, seg_len[j], 1.0), 0.0, 1.0)
    samples = wp[j] + t[:, None] * seg[j]
    sample_swath = np.where(transit[j], -1, swath[j])
    at_start = transit[j] & (s - cum[j] <= _TOL)
    at_end = transit[j] & (cum[j + 1] - s <= _TOL)
    sample_swath = np.where(at_start, swath[j], sample_swath)
    sample_swath = np.where(at_end, swath[j + 1], sample_swath)
    return SurveyPlan(
        wp, swath, samples=samples, sample_swath=sample_swath, transit=transit, **fields
    )
