"""Stops on ground-control points in a field folder: ``stops.csv`` (docs/field-format.md).

A rover that stands on a surveyed mark records it: the operator presses "on GCP3" (or the
rover's software logs the mark it parked on). The file lists those moments on the rover clock,

``stops.csv``
    ``t_s`` (rover clock, s) or ``k`` (keyframe row of ``odometry.csv``, from 0), and
    ``control_id`` (the point's id in the control file). One row per keyframe spent on the
    mark (a rover parked 10 s over a point at a keyframe every 2 s writes 5 rows).

Each row goes to its keyframe (``k``, or the keyframe nearest ``t_s``); the result is the
log's ``control_id`` column (:class:`factorgraph.log.MeasurementLog`), which
:func:`factorgraph.localize` turns into position priors (docs/ground-control.md). Rows not
used are counted by reason: ``empty_control_id``, ``off_keyframe`` (``t_s`` farther than the
sync tolerance from every keyframe), ``keyframe_out_of_range`` (``k``), ``duplicate_stop``
(the same point at the same keyframe again). Two different points at one keyframe cannot
both be under the rover: an error naming the keyframe.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from terrain.atomic import atomic_path
from terrain.errors import bad_input

from .table import csv_dialect

__all__ = ["STOPS_FILE", "read_stops", "write_stops"]

#: Default file name of the stops table in a field folder.
STOPS_FILE = "stops.csv"


def _id_text(v) -> str:
    """An id cell as text: ``7`` stays ``"7"`` (pandas reads it as 7 or 7.0), empty is ``""``."""
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return ""
    if isinstance(v, float) and v.is_integer():
        return str(int(v))
    return str(v).strip()


def read_stops(path: str | Path, t_kf: np.ndarray, tol_s: float) -> tuple[np.ndarray, Counter, int]:
    """The ``control_id`` of every keyframe from ``stops.csv``.

    Parameters
    ----------
    path : path
        ``stops.csv``: ``t_s`` or ``k``, and ``control_id``.
    t_kf : ndarray of shape (K,)
        Keyframe times, rover clock (s).
    tol_s : float
        Largest gap between a ``t_s`` and its keyframe (s).

    Returns
    -------
    control_id : ndarray of shape (K,), str
        The point the rover stood on at each keyframe; ``""`` for none.
    skipped : collections.Counter
        Rows not used, by reason.
    n_rows : int
        Rows in the file.
    """
    import pandas as pd

    path = Path(path)
    try:
        df = pd.read_csv(
            path, dtype={"control_id": str}, keep_default_na=False, **csv_dialect(path)
        )
    except (ValueError, OSError) as exc:
        raise bad_input(path.name, str(exc)[:120], "a readable CSV table", "repair it") from exc
    df.columns = [str(c).strip() for c in df.columns]
    if "control_id" not in df.columns or not ({"t_s", "k"} & set(df.columns)):
        raise bad_input(
            path.name,
            sorted(df.columns),
            "columns control_id and t_s (rover clock) or k (keyframe row)",
            "see docs/field-format.md (stops.csv)",
        )
    K = len(t_kf)
    skipped: Counter = Counter()
    ids = np.array([_id_text(v) for v in df["control_id"].tolist()], dtype=object)
    ok = ids != ""
    skipped["empty_control_id"] += int((~ok).sum())
    if "k" in df.columns:
        k = pd.to_numeric(df["k"], errors="coerce").to_numpy(float)
        inside = np.isfinite(k) & (k >= 0) & (k < K) & (k == np.round(k))
        skipped["keyframe_out_of_range"] += int((ok & ~inside).sum())
        ok &= inside
        k = np.where(ok, k, 0).astype(int)
    else:
        ts = pd.to_numeric(df["t_s"], errors="coerce").to_numpy(float)
        i = np.clip(np.searchsorted(t_kf, np.where(np.isfinite(ts), ts, np.inf)), 1, K - 1)
        k = np.where(np.abs(ts - t_kf[i - 1]) <= np.abs(ts - t_kf[i]), i - 1, i)
        near = np.isfinite(ts) & (np.abs(ts - t_kf[k]) <= tol_s)
        skipped["off_keyframe"] += int((ok & ~near).sum())
        ok &= near
    out = np.full(K, "", dtype=object)
    for row in np.flatnonzero(ok):
        kk, name = int(k[row]), str(ids[row])
        if out[kk] == name:
            skipped["duplicate_stop"] += 1
        elif out[kk]:
            raise bad_input(
                f"{path.name} row {row + 2}",
                f"{name!r} at keyframe {kk}, which already stands on {out[kk]!r}",
                "one control point per keyframe",
                "fix the stop times or ids",
            )
        else:
            out[kk] = name
    return out.astype(str), Counter({r: n for r, n in skipped.items() if n}), len(df)


def write_stops(path: str | Path, t_kf: np.ndarray, control_id: np.ndarray) -> Path | None:
    """Write the stop keyframes of ``control_id`` (K,) as ``stops.csv`` (``t_s`` at 17
    significant digits, ``k``, ``control_id``) atomically; remove a stale file and return
    None when there are none."""
    path = Path(path)
    ids = np.asarray(control_id, dtype=str) if control_id is not None else np.zeros(0, str)
    ks = np.flatnonzero(ids != "")
    if ks.size == 0:
        path.unlink(missing_ok=True)
        return None
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write("t_s,k,control_id\n")
            for k in ks:
                name = str(ids[k])
                if any(c in name for c in ',"\n\r'):
                    raise bad_input("control_id", name, 'an id without , " or newlines', "")
                fh.write(f"{float(t_kf[k]):.17g},{int(k)},{name}\n")
    return path
