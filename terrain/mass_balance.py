"""The geodetic mass balance of a volume change: metres of water equivalent, per year.

What glaciologists report and compare (WGMS; Zemp et al. 2013; Hugonnet et al. 2021) is not
the volume change but the glacier-wide *specific* mass balance, the mass change spread over
the glacier's area as a depth of water,

    B = dM / (A rho_w)            [m w.e.]        (rho_w = 1000 kg m^-3)

and its rate ``B / dt`` [m w.e. a^-1] between the two surveys' dates, beside the mean
elevation change rate ``dh / dt`` [m a^-1]. The 1-sigma follow from the volume change's
(``dM`` carries the volume's and the density's, Huss 2013); the area ``A`` is the outline's
cells inside the change grid, taken as exact (an inventory outline's own error, a few %, is
not in it), and the dates as exact (days: far below the error).
"""

from __future__ import annotations

import datetime as dt
from typing import Any

from .errors import bad_input

__all__ = ["DAYS_PER_YEAR", "WATER_DENSITY", "mass_balance", "survey_date_attrs", "survey_years"]

#: Observation times below this are relative (s since a log's start), not UTC (1973-03-03).
_POSIX_MIN = 1.0e8

#: kg m^-3: metres of water equivalent.
WATER_DENSITY = 1000.0
#: Days of a Julian year: decimal years between two dates.
DAYS_PER_YEAR = 365.25


def survey_date_attrs(t_s: Any) -> dict[str, str]:
    """A map's ``survey_date`` (the UTC date of its samples' median time, ISO) and
    ``survey_period`` (first / last date) from its samples' observation times ``t_s``
    (POSIX seconds, as a GNSS log's fixes carry them); ``{}`` when there are none or they
    are relative (a rover's landmarks: seconds since its log's start)."""
    import numpy as np

    if t_s is None:
        return {}
    t = np.asarray(t_s, float).ravel()
    t = t[np.isfinite(t)]
    if not t.size or float(t.min()) < _POSIX_MIN:
        return {}

    def day(v: float) -> str:
        return dt.datetime.fromtimestamp(v, dt.UTC).date().isoformat()

    return {
        "survey_date": day(float(np.median(t))),
        "survey_period": f"{day(float(t.min()))}/{day(float(t.max()))}",
    }


def survey_years(dates: Any, field: str = "--dates") -> tuple[float, tuple[str, str]]:
    """Years between two ISO dates (``("2015-08-01", "2024-08-20")``) and the dates.

    Raises
    ------
    InputError
        Not two ISO dates (``YYYY-MM-DD``), or the later not after the earlier.
    """
    try:
        before, after = (dt.date.fromisoformat(str(d).strip()) for d in dates)
    except (TypeError, ValueError) as exc:
        raise bad_input(field, dates, "two ISO dates, BEFORE's then AFTER's",
                        "e.g. --dates 2015-08-01 2024-08-20") from exc  # fmt: skip
    if after <= before:
        raise bad_input(field, f"{before} -> {after}", "AFTER's date after BEFORE's",
                        "give BEFORE's survey date first")  # fmt: skip
    return (after - before).days / DAYS_PER_YEAR, (before.isoformat(), after.isoformat())


def mass_balance(vc: Any, dates: Any = None) -> dict[str, Any]:
    """The specific mass balance of ``vc`` (:class:`terrain.volume.VolumeChange`), over the
    period and, with ``dates`` (two ISO dates), per year.

    Returns
    -------
    dict
        ``specific_mwe``, ``specific_std_mwe`` (m w.e. over the period); with ``dates``:
        ``dates``, ``years``, ``rate_mwe_a``, ``rate_std_mwe_a`` (m w.e. a^-1),
        ``dhdt_m_a``, ``dhdt_std_m_a`` (m a^-1); ``note`` in words.
    """
    area = float(vc.area_m2)
    out: dict[str, Any] = {
        "specific_mwe": float(vc.mass_kg) / (area * WATER_DENSITY),
        "specific_std_mwe": float(vc.mass_std_kg) / (area * WATER_DENSITY),
        "water_density_kg_m3": WATER_DENSITY,
    }
    if dates is None:
        out["note"] = (
            f"B = {out['specific_mwe']:+.3f} +- {out['specific_std_mwe']:.3f} m w.e. over the "
            "period (no --dates: no annual rate)"
        )
        return out
    years, iso = survey_years(dates)
    out.update(
        dates=list(iso),
        years=years,
        rate_mwe_a=out["specific_mwe"] / years,
        rate_std_mwe_a=out["specific_std_mwe"] / years,
        dhdt_m_a=float(vc.mean_dh_m) / years,
        dhdt_std_m_a=float(vc.mean_dh_std_m) / years,
    )
    out["note"] = (
        f"B = {out['rate_mwe_a']:+.3f} +- {out['rate_std_mwe_a']:.3f} m w.e. a^-1 over "
        f"{years:.2f} years ({iso[0]} to {iso[1]}); dh/dt {out['dhdt_m_a']:+.3f} +- "
        f"{out['dhdt_std_m_a']:.3f} m a^-1"
    )
    return out
