"""Vertical mapping-accuracy standards, each rule labelled with the document it comes from.

All lengths are metres; feet appear only in labels (1 ft = 0.3048 m exactly). Standards:

``"paper"``      the paper's Tables I-III as published (RMSE = CI/6 for every class).
``"asprs1990"``  ASPRS Accuracy Standards for Large-Scale Maps (1990): CI/3, 2CI/3, CI for
                 contours, CI/6, CI/3, CI/2 for spot heights (docs/architecture.md §5).
``"asprs2014"``  ASPRS Positional Accuracy Standards for Digital Geospatial Data, Ed. 1 (2014).
``"asprs2023"``  the same, Edition 2, Version 1.0 (August 2023).
``"nssda"``      FGDC-STD-007.3-1998, National Standard for Spatial Data Accuracy.
``"nmas"``       United States National Map Accuracy Standards (1947).

Section and table numbers marked "(unverified)" are quoted from memory, not checked against
the documents; the numbers themselves are the published ones unless said otherwise.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass
from typing import Any

from terrain.errors import bad_input

__all__ = [
    "CHECKPOINT_COUNTS",
    "CHECKPOINT_RATIO",
    "FOOT_M",
    "NMAS_CI_DIVISOR",
    "NMAS_FACTOR",
    "NSSDA_FACTOR",
    "STANDARDS",
    "VVA_FACTOR_2014",
    "Standard",
    "VerticalClass",
    "accuracy_95",
    "class_achieved",
    "combined_rmse_with_checkpoints",
    "finest_contour_interval",
    "list_classes",
    "max_rmse",
    "min_checkpoints",
    "verdicts",
]

FOOT_M = 0.3048  # international foot, exact by definition (1959)
NSSDA_FACTOR = 1.9600  # FGDC-STD-007.3-1998 App. 3-A: Accuracy_z = 1.9600 * RMSE_z (95 %)
NMAS_FACTOR = 1.6449  # FGDC-STD-007.3-1998 App. 3-D: VMAS = 1.6449 * RMSE_z (90 %)
NMAS_CI_DIVISOR = 3.2898  # VMAS <= CI/2  =>  RMSE_z <= CI / (2 * 1.6449); ASPRS 2014 Table B.7
VVA_FACTOR_2014 = 3.0  # ASPRS 2014 Table 7.5: VVA (95th percentile) = 3.0 * RMSE_z of the class
# Checkpoints must be this many times more accurate than the accuracy being tested:
CHECKPOINT_RATIO = {
    "asprs2014": 3.0,  # ASPRS 2014 sec. 7.9 "Checkpoint Accuracy and Placement" (sec. unverified)
    "asprs2023": 2.0,  # ASPRS Ed. 2 (2023) summary of changes: relaxed from 3x to "two times"
}
_FEATURES = ("contour", "spot")
_TOL = 1e-12  # relative slack on a limit, for floating-point round-off only
_CI_TOL_M = 1e-6  # a contour interval matches a tabulated one within 1 micrometre


@dataclass(frozen=True)
class VerticalClass:
    """One rule of a standard: the largest vertical RMSE a class allows.

    Attributes
    ----------
    standard, name : str
        Registry key of the standard and class name (``"1"``, ``"10-cm"``, ``"NMAS"``).
    max_rmse_m : float or None
        Fixed limit on RMSE_z in metres; None when the limit scales with the contour interval.
    contour_interval_m : float or None
        The tabulated contour interval (m) this row applies to (paper only).
    feature : str
        ``"contour"``, ``"spot"`` or ``"any"`` (rule does not distinguish).
    source : str
        Document and table/section the number is taken from.
    ci_fraction : float or None
        Limit = ``ci_fraction`` * contour interval (ASPRS 1990, NMAS).
    nva_95_m, vva_95p_m : float or None
        ASPRS 2014 class limits on NVA at 95 % and VVA at the 95th percentile (m).
    """

    standard: str
    name: str
    max_rmse_m: float | None
    contour_interval_m: float | None
    feature: str
    source: str
    ci_fraction: float | None = None
    nva_95_m: float | None = None
    vva_95p_m: float | None = None

    def limit_m(self, contour_interval_m: float | None = None) -> float:
        """Largest RMSE_z (m) this rule allows at ``contour_interval_m`` (m)."""
        if self.ci_fraction is None:
            return float(self.max_rmse_m)  # type: ignore[arg-type]
        if contour_interval_m is None:
            fix = f"{self.standard} limits scale with the contour interval; pass one"
            raise bad_input("contour_interval_m", None, "a contour interval (m)", fix)
        return self.ci_fraction * contour_interval_m


@dataclass(frozen=True)
class Standard:
    """A standard: registry key, full title, and its rules (strictest class first)."""

    key: str
    title: str
    classes: tuple[VerticalClass, ...]


_PAPER = "paper Table {}: {} ft -> {} m (CI/6)"
_A1990 = "ASPRS 1990 Large-Scale Maps, sec. 2 vertical: Class {}: RMSE_z <= {} x {} ({})"
_A2014 = "ASPRS 2014 Table 7.5: RMSE_z (NVA); NVA95 = 1.96 RMSE_z, VVA = 3.0 RMSE_z"
_A2023 = "ASPRS Ed. 2 (2023) vertical accuracy classes, RMSE_z only (table no. unverified)"
_NMAS = "NMAS 1947 item 2 (90 % within CI/2) -> RMSE_z <= CI/3.2898 (FGDC App. 3-D)"
# X-cm classes: published RMSE_z in cm (ASPRS 2014 Table 7.5); 33.3/66.7/333.3 print rounded.
_X_CM = ("1", "2.5", "5", "10", "15", "20", "33.3", "66.7", "100", "333.3")

# fmt: off
_PAPER_TABLES = {  # paper Sec. III-C, (CI in ft, RMSE in m) exactly as printed
    "I":   [(1, 0.0508), (2, 0.1016), (3, 0.1524)],  # Table I   (Class 1)
    "II":  [(2, 0.1016), (4, 0.2032), (6, 0.3048)],  # Table II  (Class 2)
    "III": [(3, 0.1524), (6, 0.3048), (9, 0.4572)],  # Table III (Class 3)
}
STANDARDS: dict[str, Standard] = {
    "paper": Standard("paper", "Paper Tables I-III as published (RMSE = CI/6)", tuple(
        VerticalClass("paper", str(len(t)), r, ft * FOOT_M, "any", _PAPER.format(t, ft, r))
        for t, rows in _PAPER_TABLES.items() for ft, r in rows)),
    # ASPRS (1990) PE&RS 56(7):1068-1070: Class 1 limiting RMSE = CI/3 for topographic
    # (contour) points, CI/6 for spot/DTM points; Class 2 = 2x and Class 3 = 3x Class 1.
    "asprs1990": Standard("asprs1990", "ASPRS Accuracy Standards for Large-Scale Maps (1990)",
        tuple(VerticalClass("asprs1990", str(k), None, None, f, _A1990.format(k, k, lab, f),
                            ci_fraction=k * base)
              for f, base, lab in (("contour", 1 / 3, "CI/3"), ("spot", 1 / 6, "CI/6"))
              for k in (1, 2, 3))),
    "asprs2014": Standard("asprs2014", "ASPRS Positional Accuracy Standards, Ed. 1 (2014)",
        tuple(VerticalClass("asprs2014", f"{x}-cm", m, None, "any", _A2014,
                            nva_95_m=NSSDA_FACTOR * m, vva_95p_m=VVA_FACTOR_2014 * m)
              for x in _X_CM for m in [float(x + "e-2")])),
    # Ed. 2 keeps X-cm classes by RMSE_z; 95 % statements dropped, VVA reported "as found".
    "asprs2023": Standard("asprs2023", "ASPRS Positional Accuracy Standards, Ed. 2 (2023)",
        tuple(VerticalClass("asprs2023", f"{x}-cm", float(x + "e-2"), None, "any", _A2023)
              for x in _X_CM)),
    "nssda": Standard("nssda", "NSSDA, FGDC-STD-007.3-1998 (reporting only, no classes)", ()),
    "nmas": Standard("nmas", "U.S. National Map Accuracy Standards (1947)", (
        VerticalClass("nmas", "NMAS", None, None, "any", _NMAS, ci_fraction=1 / NMAS_CI_DIVISOR),
    )),
}

# Minimum NVA checkpoints: rows of (largest project area in km2, count); None = no count set.
CHECKPOINT_COUNTS: dict[str, tuple[tuple[float, int], ...] | None] = {
    "paper": None,                   # the paper sets no count
    "nmas": None,                    # the 1947 text sets no count
    "asprs1990": ((math.inf, 20),),  # ASPRS 1990: at least 20 checkpoints (section unverified)
    "nssda": ((math.inf, 20),),      # FGDC-STD-007.3-1998 sec. 3.2.1: "a minimum of 20"
    # ASPRS 2014 Annex C Table C.1, NVA column (from memory); the table stops at 2500 km2,
    # larger areas keep its last row here.
    "asprs2014": ((500, 20), (750, 20), (1000, 25), (1250, 30), (1500, 35), (1750, 40),
                  (2000, 45), (2250, 50), (2500, 55), (math.inf, 55)),
    # ASPRS Ed. 2 (2023): minimum 30, maximum 120 (summary of changes). The growth of +5 per
    # further 500 km2 above 1000 km2 is from memory and UNVERIFIED.
    "asprs2023": tuple((1000.0 + 500.0 * i, 30 + 5 * i) for i in range(18)) + ((math.inf, 120),),
}
# fmt: on


# --------------------------------------------------------------------------- validation
def _num(value: Any, field: str, expected: str, fix: str, positive: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not math.isfinite(v) or v < 0 or (positive and v == 0):
        raise bad_input(field, value, expected, fix)
    return v


def _standard(standard: Any) -> Standard:
    if not isinstance(standard, str) or standard not in STANDARDS:
        raise bad_input("standard", standard, f"one of {sorted(STANDARDS)}", "use a listed name")
    return STANDARDS[standard]


def _rmse(value: Any, field: str = "rmse_m") -> float:
    return _num(value, field, "a finite RMSE >= 0 (m)", "pass RMSE in metres, not NaN/negative")


def _ci(value: Any, required: bool, who: str) -> float | None:
    if value is None and not required:
        return None
    fix = f"{who} needs a positive contour interval in metres (1 ft = 0.3048 m)"
    return _num(value, "contour_interval_m", "a finite contour interval > 0 (m)", fix, True)


def _needs_ci(std: Standard) -> bool:
    return std.key in ("paper", "asprs1990", "nmas")


def _feature(feature: Any) -> str:
    if feature not in _FEATURES:
        raise bad_input("feature", feature, f"one of {list(_FEATURES)}", "contour or spot height")
    return feature


def _rules(std: Standard, feature: str, name: Any = None) -> list[VerticalClass]:
    """Rules of ``std`` for ``feature`` (and class ``name`` if given), strictest first."""
    if std.key == "nssda":
        fix = "NSSDA only reports Accuracy_z: use accuracy_95(rmse_m, 'nssda')"
        raise bad_input("standard", "nssda", "a standard with classes", fix)
    rules = [c for c in std.classes if c.feature in ("any", feature)]
    if name is not None:
        rules = [c for c in rules if c.name == name]
        if not rules:
            names = list(dict.fromkeys(c.name for c in std.classes))
            raise bad_input("class_name", name, f"one of {names} ({std.key})", "use a listed name")
    return rules


def _at_ci(rules: list[VerticalClass], ci: float | None, value: Any) -> list[VerticalClass]:
    """Paper only: keep the rows tabulated at ``ci``; InputError listing them if none."""
    if not rules or rules[0].standard != "paper":
        return rules
    hit = [c for c in rules if abs(c.contour_interval_m - ci) <= _CI_TOL_M]
    if not hit:
        tab = sorted({round(c.contour_interval_m, 4) for c in rules})
        fix = "the paper tabulates only these; use 'asprs1990' for any interval"
        raise bad_input("contour_interval_m", value, f"one of {tab} m", fix)
    return hit


def _meets(rmse: float, limit: float) -> bool:
    return rmse <= limit * (1.0 + _TOL)


# --------------------------------------------------------------------------- public API
def list_classes(standard: str) -> list[VerticalClass]:
    """All rules of ``standard``, strictest class first (empty for ``"nssda"``)."""
    return list(_standard(standard).classes)


def max_rmse(
    standard: str,
    class_name: str,
    contour_interval_m: float | None = None,
    feature: str = "contour",
) -> float:
    """Largest vertical RMSE (m) that ``class_name`` allows at a contour interval (m).

    ``"paper"`` accepts only its tabulated intervals (no extension); ``"asprs1990"`` and
    ``"nmas"`` apply their formula to any interval; the X-cm standards ignore the interval.
    """
    std, feat = _standard(standard), _feature(feature)
    ci = _ci(contour_interval_m, _needs_ci(std), std.key)
    return _at_ci(_rules(std, feat, class_name), ci, contour_interval_m)[0].limit_m(ci)


def class_achieved(
    rmse_m: float, standard: str, contour_interval_m: float | None = None, feature: str = "contour"
) -> str | None:
    """Strictest class whose limit at ``contour_interval_m`` (m) is >= ``rmse_m`` (m), or None.

    For the X-cm standards: the finest class whose RMSE_z limit is >= ``rmse_m``.
    """
    rmse, std, feat = _rmse(rmse_m), _standard(standard), _feature(feature)
    ci = _ci(contour_interval_m, _needs_ci(std), std.key)
    rules = _at_ci(_rules(std, feat), ci, contour_interval_m)
    return next((c.name for c in rules if _meets(rmse, c.limit_m(ci))), None)


def finest_contour_interval(
    rmse_m: float, standard: str, class_name: str | None = None, feature: str = "contour"
) -> float | None:
    """Finest contour interval (m) at which ``rmse_m`` (m) still meets ``class_name``.

    ``class_name=None`` means the strictest class. ``"paper"`` returns the finest *tabulated*
    interval (None if none qualifies). ``"asprs2014"`` uses its Table B.7 equivalence, which is
    the ASPRS 1990 formula (Class 1: CI = 3 RMSE_z, Class 2: CI = 1.5 RMSE_z).
    """
    rmse, std, feat = _rmse(rmse_m), _standard(standard), _feature(feature)
    if std.key == "asprs2014":
        std = STANDARDS["asprs1990"]
    elif std.key in ("asprs2023", "nssda"):
        ok = "'paper', 'asprs1990', 'asprs2014' or 'nmas'"
        raise bad_input("standard", standard, ok, "no contour equivalence is tabulated for it")
    rules = _rules(std, feat, _rules(std, feat)[0].name if class_name is None else class_name)
    if std.key == "paper":
        ok_ci = [c.contour_interval_m for c in rules if _meets(rmse, c.limit_m())]
        return min(ok_ci) if ok_ci else None
    return rmse / rules[0].ci_fraction


def accuracy_95(rmse_m: float, standard: str = "nssda") -> float:
    """Vertical accuracy at 95 % confidence (m): 1.9600 * RMSE_z (NSSDA; ASPRS 2014 NVA)."""
    rmse = _rmse(rmse_m)
    if _standard(standard).key not in ("nssda", "asprs2014"):
        fix = "only NSSDA and ASPRS 2014 state 95 % (Ed. 2 dropped it; NMAS is a 90 % rule)"
        raise bad_input("standard", standard, "'nssda' or 'asprs2014'", fix)
    return NSSDA_FACTOR * rmse


def combined_rmse_with_checkpoints(rmse_m: float, checkpoint_rmse_m: float) -> float:
    """Product RMSE_z including checkpoint survey error (ASPRS Ed. 2, 2023), in metres.

    ``sqrt(rmse_m**2 + checkpoint_rmse_m**2)``: Ed. 2 "inclusion of survey checkpoint
    accuracy" in the product accuracy (section number unverified).
    """
    return math.hypot(_rmse(rmse_m), _rmse(checkpoint_rmse_m, "checkpoint_rmse_m"))


def min_checkpoints(standard: str, area_km2: float | None = None) -> int | None:
    """Minimum number of vertical (NVA) checkpoints for a project of ``area_km2`` (km2).

    None when the standard sets no count. ``area_km2=None`` gives the smallest-area row.
    """
    rows = CHECKPOINT_COUNTS[_standard(standard).key]
    a = 0.0 if area_km2 is None else _num(area_km2, "area_km2", "a finite area >= 0", "km2")
    return None if rows is None else next(n for top, n in rows if a <= top)


def verdicts(
    rmse_m: float,
    contour_interval_m: float,
    checkpoint_rmse_m: float = 0.0,
    n_checkpoints: int | None = None,
    *,
    feature: str = "contour",
    area_km2: float | None = None,
) -> list[dict[str, Any]]:
    """One row per standard, for the accuracy certificate.

    Parameters
    ----------
    rmse_m : float
        Vertical RMSE of the map against checkpoints (m).
    contour_interval_m : float
        Contour interval the map is certified for (m).
    checkpoint_rmse_m : float, optional
        RMSE of the checkpoint survey itself (m); 0 for exact (synthetic) truth.
    n_checkpoints : int, optional
        Number of checkpoints used; None skips the count check.
    feature : {"contour", "spot"}
        ASPRS 1990 feature type.
    area_km2 : float, optional
        Project area (km2) for the checkpoint counts.

    Returns
    -------
    list of dict
        Keys: ``standard``, ``title``, ``class`` (strictest class met or None), ``passed``
        (None when the standard has no pass/fail at this interval), ``rmse_m`` (RMSE tested,
        with checkpoint error for ``asprs2023``), ``limit_m`` (limit of the class met, else of
        the loosest class), ``checkpoints_ok`` (count and checkpoint-accuracy checks; None if
        not checked), ``notes`` and ``source``. ``passed`` needs a class and no failed
        checkpoint check. For ASPRS 2014/2023 the class met also needs checkpoints 3x / 2x
        more accurate than its limit.
    """
    rmse, cp = _rmse(rmse_m), _rmse(checkpoint_rmse_m, "checkpoint_rmse_m")
    ci, feat = _ci(contour_interval_m, True, "verdicts"), _feature(feature)
    if n_checkpoints is not None:
        try:
            ok = operator.index(n_checkpoints) >= 0
        except TypeError:
            ok = False
        if not ok:
            raise bad_input("n_checkpoints", n_checkpoints, "an int >= 0 or None", "count them")
    rows = []
    for key, std in STANDARDS.items():
        used = combined_rmse_with_checkpoints(rmse, cp) if key == "asprs2023" else rmse
        need = min_checkpoints(key, area_km2)
        cp_ok = None if n_checkpoints is None or need is None else n_checkpoints >= need
        notes = [f"{n_checkpoints} checkpoints < minimum {need}"] if cp_ok is False else []
        cls = limit = passed = None
        source = std.title
        tabulated = key != "paper" or any(
            abs(c.contour_interval_m - ci) <= _CI_TOL_M for c in std.classes
        )
        if key == "nssda":
            notes.append(f"Accuracy_z = 1.9600 x RMSE_z = {accuracy_95(rmse):.4f} m (95 %)")
            source = "FGDC-STD-007.3-1998 App. 3-A"
        elif key == "paper" and not tabulated:
            notes.append(f"{ci:g} m is not a contour interval of paper Tables I-III")
        else:
            ratio = CHECKPOINT_RATIO.get(key, 0.0)
            rules = _at_ci(_rules(std, feat), ci, ci)
            chosen = rules[-1]
            for c in rules:
                if _meets(used, c.limit_m(ci)) and _meets(cp * ratio, c.limit_m(ci)):
                    cls, chosen = c.name, c
                    break
            limit, source = chosen.limit_m(ci), chosen.source
            if not _meets(cp * ratio, limit):
                cp_ok = False
                notes.append(f"checkpoints must be {ratio:g}x more accurate than {limit:.4f} m")
            passed = cls is not None and cp_ok is not False
            if key == "asprs2014":
                notes.append(f"NVA = 1.96 x RMSE_z = {NSSDA_FACTOR * rmse:.4f} m (95 %)")
                notes.append(
                    f"Table B.7: ASPRS 1990 Class 1 equivalent CI = 3 x RMSE_z = {3 * rmse:.4f} m"
                )
            if key == "asprs2023":
                notes.append(f"RMSE_z incl. checkpoints = sqrt({rmse:.4f}^2 + {cp:.4f}^2)")
        row = dict(standard=key, title=std.title, rmse_m=used, limit_m=limit, notes=notes)
        rows.append(
            row | {"class": cls, "passed": passed, "checkpoints_ok": cp_ok, "source": source}
        )
    return rows
