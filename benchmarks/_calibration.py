"""Calibration of a stated 1-sigma over seeds (the ground-control benchmark's ``--calibration``
sweep, docs/ground-control.md "Is the shared sigma honest?"): seed ranges, a failure-tolerant
row, and the per-case z-score table."""

from __future__ import annotations

from typing import Any

import numpy as np


def guarded(func, *args) -> dict[str, Any]:
    """``func(*args)``, or a row naming the failure (a sweep over seeds goes on; counted)."""
    try:
        return func(*args)
    except Exception as exc:  # reported in the row and in the calibration's n_failed
        return {"case": args[0], "seed": args[1], "error": f"{type(exc).__name__}: {exc}"}


def seed_list(tokens: list[str]) -> list[int]:
    """``["0-3", "7"]`` -> ``[0, 1, 2, 3, 7]`` (inclusive ranges)."""
    out: list[int] = []
    for tok in tokens:
        a, _, b = tok.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


#: realised offsets scored against the stated shared vertical 1-sigma (same sign: map - truth)
Z_SOURCES = (
    ("keyframe_z_mean_m", "kf"),  # what the marginals' shared covariance describes exactly
    ("map_mean_error_m", "map"),  # the map's mean error over the site
    ("checkpoint_bias_m", "cp"),  # the certificate's bias (DEM - checkpoint), 400 points
)


def calibration(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per case, over seeds: z = offset / stated shared 1-sigma for each of :data:`Z_SOURCES`;
    std of z (1 when the sigma is honest), RMS of z with its 90 % interval for a calibrated
    sigma (chi-square with n degrees of freedom), the share with |z| < 1.96 (0.95)."""
    from scipy.stats import chi2

    out = []
    for case in dict.fromkeys(r["case"] for r in rows):
        ok = [r for r in rows if r["case"] == case and "error" not in r]
        n = len(ok)
        row: dict[str, Any] = {
            "case": case,
            "n": n,
            "n_failed": sum(r["case"] == case for r in rows) - n,
        }
        if n == 0:
            out.append(row)
            continue
        sig = np.array([r["shared_z_std_m"] for r in ok])
        row["shared_z_std_median_m"] = float(np.median(sig))
        lo, hi = np.sqrt(chi2.ppf([0.05, 0.95], n) / n)
        row["rms_z_90_if_calibrated"] = [float(lo), float(hi)]
        for key, tag in Z_SOURCES:
            if any(r.get(key) is None for r in ok):  # --route small: no map, no checkpoints
                continue
            z = np.array([r[key] for r in ok]) / sig
            row[f"z_{tag}"] = [round(float(v), 3) for v in z]
            row[f"{tag}_z_mean"] = float(z.mean())
            row[f"{tag}_z_std"] = float(z.std(ddof=1)) if n > 1 else None
            row[f"{tag}_z_rms"] = float(np.sqrt(np.mean(z**2)))
            row[f"{tag}_in_1.96"] = float(np.mean(np.abs(z) < 1.96))
        # what the map and the checkpoints add to the shared offset (m, RMS over seeds): the
        # map's own mean error (prior, GP shape, along-track), which no stated sigma names
        kf = np.array([r["keyframe_z_mean_m"] for r in ok])
        for key, tag in Z_SOURCES[1:]:
            if any(r.get(key) is None for r in ok):
                continue
            d = np.array([r[key] for r in ok]) - kf
            row[f"{tag}_minus_kf_rms_m"] = float(np.sqrt(np.mean(d**2)))
        out.append(row)
    return out


CALIBRATION_COLUMNS = [
    ("case", "case", ""),
    ("n", "seeds", "d"),
    ("shared_z_std_median_m", "shared z σ", ".3f"),
    *[
        c
        for _, t in Z_SOURCES
        for c in (
            (f"{t}_z_mean", f"{t} z mean", "+.2f"),
            (f"{t}_z_std", f"{t} z std", ".2f"),
            (f"{t}_z_rms", f"{t} z RMS", ".2f"),
            (f"{t}_in_1.96", f"{t} |z|<1.96", ".2f"),
        )
    ],
    ("map_minus_kf_rms_m", "map-kf RMS", ".3f"),
    ("cp_minus_kf_rms_m", "cp-kf RMS", ".3f"),
]
