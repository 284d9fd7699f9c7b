"""Mapping-accuracy standards checked against their published numbers (source beside each)."""

import math

import pytest

from survey.standards import (
    CHECKPOINT_RATIO,
    NMAS_CI_DIVISOR,
    NMAS_FACTOR,
    NSSDA_FACTOR,
    STANDARDS,
    VVA_FACTOR_2014,
    accuracy_95,
    class_achieved,
    combined_rmse_with_checkpoints,
    finest_contour_interval,
    list_classes,
    max_rmse,
    min_checkpoints,
    verdicts,
)
from terrain.errors import InputError

FT = 0.3048  # international foot, exact

# (class, contour interval m, published RMSE m) -- paper Sec. III-C, Tables I-III as printed
PAPER_ROWS = [
    ("1", 0.3048, 0.0508),  # paper Table I:   0.3048 m (1 ft) -> 0.0508 m
    ("1", 0.6096, 0.1016),  # paper Table I:   0.6096 m (2 ft) -> 0.1016 m
    ("1", 0.9144, 0.1524),  # paper Table I:   0.9144 m (3 ft) -> 0.1524 m
    ("2", 0.6096, 0.1016),  # paper Table II:  0.6096 m (2 ft) -> 0.1016 m
    ("2", 1.2192, 0.2032),  # paper Table II:  1.2192 m (4 ft) -> 0.2032 m
    ("2", 1.8288, 0.3048),  # paper Table II:  1.8288 m (6 ft) -> 0.3048 m
    ("3", 0.9144, 0.1524),  # paper Table III: 0.9144 m (3 ft) -> 0.1524 m
    ("3", 1.8288, 0.3048),  # paper Table III: 1.8288 m (6 ft) -> 0.3048 m
    ("3", 2.7432, 0.4572),  # paper Table III: 2.7432 m (9 ft) -> 0.4572 m
]


@pytest.mark.parametrize(("cls", "ci", "rmse"), PAPER_ROWS)
def test_paper_tables_as_published(cls, ci, rmse):
    assert max_rmse("paper", cls, ci) == pytest.approx(rmse, abs=1e-12)
    assert rmse == pytest.approx(ci / 6, abs=1e-12)  # paper text: "no greater than K/6"
    assert ci / FT == pytest.approx(round(ci / FT), abs=1e-12)  # whole feet


def test_paper_registry_has_nine_rows_in_feet():
    rows = list_classes("paper")
    assert len(rows) == 9
    got = [(r.name, round(r.contour_interval_m / FT), r.max_rmse_m) for r in rows]
    # paper Tables I-III: Class 1 at 1,2,3 ft; Class 2 at 2,4,6 ft; Class 3 at 3,6,9 ft
    assert got == [(c, round(ci / FT), r) for c, ci, r in PAPER_ROWS]
    assert all("paper Table" in r.source for r in rows)


def test_paper_class_achieved():
    assert class_achieved(0.4572, "paper", 2.7432) == "3"  # paper Table III limit, exactly
    assert class_achieved(0.46, "paper", 2.7432) is None  # above 0.4572 m (prose rounds to 0.46)
    assert class_achieved(0.2827, "paper", 2.7432) == "3"  # paper Sec. IV lawnmower RMSE
    assert class_achieved(0.15, "paper", 0.9144) == "1"  # 3 ft: Tables I, II, III all 0.1524 m
    assert class_achieved(0.16, "paper", 0.9144) is None
    assert class_achieved(0.2, "paper", 1.2192) == "2"  # 4 ft: only Table II, 0.2032 m


def test_paper_only_tabulated_intervals():
    with pytest.raises(InputError, match="contour_interval_m"):
        max_rmse("paper", "1", 2.7432)  # 9 ft is only in Table III
    with pytest.raises(InputError, match="contour_interval_m"):
        class_achieved(0.1, "paper", 1.0)  # 1 m is in no table
    assert finest_contour_interval(0.2, "paper", "3") == pytest.approx(1.8288)  # 6 ft: 0.3048
    assert finest_contour_interval(0.05, "paper") == pytest.approx(0.3048)  # Class 1, 1 ft
    assert finest_contour_interval(0.5, "paper", "3") is None  # > 0.4572 m, the loosest row


def test_asprs1990_contours_and_spot_heights():
    # ASPRS 1990 Large-Scale Maps: Class 1 = CI/3 (contour), CI/6 (spot); Class 2 = 2x; Class 3 = 3x
    expected = {
        ("1", "contour"): 1 / 3,  # 0.333 m at CI = 1 m
        ("2", "contour"): 2 / 3,  # 0.667 m
        ("3", "contour"): 1.0,  # 1.0 m
        ("1", "spot"): 1 / 6,  # 0.1667 m
        ("2", "spot"): 1 / 3,  # 0.333 m
        ("3", "spot"): 1 / 2,  # 0.5 m
    }
    for (cls, feat), lim in expected.items():
        assert max_rmse("asprs1990", cls, 1.0, feature=feat) == pytest.approx(lim, rel=1e-12)
    assert max_rmse("asprs1990", "1", 1.0) == pytest.approx(0.333, abs=5e-4)
    assert max_rmse("asprs1990", "2", 1.0, "spot") == pytest.approx(0.333, abs=5e-4)
    # paper's CI/6 equals ASPRS 1990 Class 1 *spot height*, not its contour limit
    # (docs/architecture.md §5)
    assert max_rmse("asprs1990", "1", 2.7432, "spot") == pytest.approx(0.4572)
    assert class_achieved(0.4572, "asprs1990", 2.7432) == "1"  # contour: 0.9144 m limit
    assert class_achieved(0.9, "asprs1990", 1.0) == "3"
    assert class_achieved(1.01, "asprs1990", 1.0) is None
    assert class_achieved(0.4, "asprs1990", 1.0, feature="spot") == "3"  # CI/2 = 0.5


def test_nssda_and_nmas_factors():
    assert NSSDA_FACTOR == 1.9600  # FGDC-STD-007.3-1998 App. 3-A: Accuracy_z = 1.9600 RMSE_z
    assert accuracy_95(0.5) == pytest.approx(0.98)
    assert accuracy_95(0.5, "asprs2014") == pytest.approx(0.98)  # ASPRS 2014 NVA at 95 %
    assert NMAS_FACTOR == 1.6449  # FGDC App. 3-D: VMAS = 1.6449 RMSE_z
    assert NMAS_CI_DIVISOR == pytest.approx(2 * 1.6449)  # VMAS <= CI/2 -> RMSE_z <= CI/3.2898
    lim = max_rmse("nmas", "NMAS", 1.0)
    assert lim == pytest.approx(1 / 3.2898)  # 0.30397 m
    assert NMAS_FACTOR * lim == pytest.approx(0.5)  # NMAS item 2: 90 % within CI/2
    assert accuracy_95(lim) == pytest.approx(0.5958, abs=5e-5)  # FGDC App. 3-D: 0.5958 CI
    assert class_achieved(0.30, "nmas", 1.0) == "NMAS"
    assert class_achieved(0.31, "nmas", 1.0) is None
    with pytest.raises(InputError, match="standard"):
        accuracy_95(0.5, "asprs2023")  # Ed. 2 dropped the 95 % statement
    with pytest.raises(InputError, match="accuracy_95"):
        class_achieved(0.1, "nssda", 1.0)  # NSSDA reports, it has no classes


def test_asprs2014_and_2023_classes():
    names = ["1-cm", "2.5-cm", "5-cm", "10-cm", "15-cm", "20-cm"]
    names += ["33.3-cm", "66.7-cm", "100-cm", "333.3-cm"]  # ASPRS 2014 Table 7.5 classes
    cm = [1, 2.5, 5, 10, 15, 20, 33.3, 66.7, 100, 333.3]  # RMSE_z (cm), Table 7.5
    nva = [2.0, 4.9, 9.8, 19.6, 29.4, 39.2, 65.3, 130.7, 196.0, 653.3]  # NVA 95 % (cm), Table 7.5
    vva = [3, 7.5, 15, 30, 45, 60, 99.9, 200.1, 300, 999.9]  # 3.0 x RMSE_z (Table 7.5 prints
    # 100, 200 and 1000 cm for the rounded classes 33.3, 66.7, 333.3)
    for key in ("asprs2014", "asprs2023"):
        rows = list_classes(key)
        assert [r.name for r in rows] == names
        assert [r.max_rmse_m for r in rows] == pytest.approx([c / 100 for c in cm])
    rows14 = list_classes("asprs2014")
    assert [r.nva_95_m for r in rows14] == pytest.approx([v / 100 for v in nva], abs=6e-4)
    assert [r.vva_95p_m for r in rows14] == pytest.approx([v / 100 for v in vva], abs=1e-9)
    assert VVA_FACTOR_2014 == 3.0
    assert all(r.nva_95_m is None and r.vva_95p_m is None for r in list_classes("asprs2023"))
    assert class_achieved(0.10, "asprs2014") == "10-cm"
    assert class_achieved(0.1001, "asprs2014") == "15-cm"
    assert class_achieved(0.2827, "asprs2023") == "33.3-cm"
    assert class_achieved(3.4, "asprs2014") is None
    assert max_rmse("asprs2023", "66.7-cm") == pytest.approx(0.667)


def test_asprs2014_table_b7_equivalent_contours():
    # ASPRS 2014 Table B.7: 10-cm class -> ASPRS 1990 Class 1 CI 30 cm, Class 2 CI 15 cm,
    # NMAS CI 32.9 cm (3.2898 x RMSE_z)
    assert finest_contour_interval(0.10, "asprs2014", "1") == pytest.approx(0.30)
    assert finest_contour_interval(0.10, "asprs2014", "2") == pytest.approx(0.15)
    assert finest_contour_interval(0.10, "nmas") == pytest.approx(0.32898)
    # 1-cm class -> 3.0 cm Class 1, 1.5 cm Class 2, 3.29 cm NMAS (Table B.7 first row)
    assert finest_contour_interval(0.01, "asprs2014") == pytest.approx(0.03)
    assert finest_contour_interval(0.01, "nmas") == pytest.approx(0.0329, abs=1e-5)


def test_checkpoint_inclusion_and_counts():
    # ASPRS Ed. 2 (2023): RMSE_z = sqrt(RMSE_data^2 + RMSE_checkpoints^2); by hand 3-4-5
    assert combined_rmse_with_checkpoints(0.03, 0.04) == pytest.approx(0.05)
    assert combined_rmse_with_checkpoints(0.2827, 0.0) == 0.2827
    assert CHECKPOINT_RATIO == {"asprs2014": 3.0, "asprs2023": 2.0}  # 2014: 3x, Ed. 2: 2x
    assert min_checkpoints("asprs2023") == 30  # Ed. 2: minimum raised from 20 to 30
    assert min_checkpoints("asprs2023", 1e6) == 120  # Ed. 2: at most 120 for large projects
    assert min_checkpoints("asprs2014") == 20  # ASPRS 2014 Table C.1, <= 500 km2
    assert min_checkpoints("asprs2014", 0.36) == 20  # the 600 m x 600 m glacier site
    assert min_checkpoints("nssda") == 20  # FGDC-STD-007.3-1998 sec. 3.2.1
    assert min_checkpoints("paper") is None and min_checkpoints("nmas") is None
    counts = [min_checkpoints("asprs2023", a) for a in (0, 1000, 1001, 1500, 1501, 5000)]
    assert counts == sorted(counts) and counts[0] == 30


def test_round_trips():
    for std, cls, feat in [
        ("asprs1990", "1", "contour"),
        ("asprs1990", "3", "spot"),
        ("nmas", "NMAS", "contour"),
    ]:
        for rmse in (0.01, 0.2827, 1.7):
            ci = finest_contour_interval(rmse, std, cls, feat)
            assert max_rmse(std, cls, ci, feat) == pytest.approx(rmse, rel=1e-12)
            assert class_achieved(rmse, std, ci, feat) in (cls, "1", "2")
    for cls, ci, rmse in PAPER_ROWS:
        assert finest_contour_interval(rmse, "paper", cls) <= ci + 1e-9
        assert max_rmse("paper", cls, finest_contour_interval(rmse, "paper", cls)) >= rmse - 1e-12


def test_verdicts_rows():
    rows = verdicts(0.2827, 2.7432, checkpoint_rmse_m=0.02, n_checkpoints=25)
    by = {r["standard"]: r for r in rows}
    assert list(by) == list(STANDARDS)
    assert by["paper"]["class"] == "3" and by["paper"]["passed"] is True
    assert by["paper"]["limit_m"] == pytest.approx(0.4572)  # paper Table III
    assert by["asprs1990"]["class"] == "1"  # 0.2827 <= 2.7432 / 3 = 0.9144
    assert by["asprs2014"]["class"] == "33.3-cm" and by["asprs2014"]["checkpoints_ok"] is True
    assert by["asprs2023"]["rmse_m"] == pytest.approx(math.hypot(0.2827, 0.02))
    assert by["asprs2023"]["passed"] is False  # 25 < 30 checkpoints (Ed. 2)
    assert by["nssda"]["passed"] is None and "0.5541" in by["nssda"]["notes"][0]  # 1.96 x
    assert by["nmas"]["passed"] is True
    assert all(r["source"] for r in rows)
    # 1 m is no paper interval: no verdict there, the others still decide
    by = {r["standard"]: r for r in verdicts(0.2827, 1.0)}
    assert by["paper"]["passed"] is None and by["asprs1990"]["class"] == "1"
    # checkpoints too coarse for the finest class: 2014 needs 3x, steps down a class
    by = {r["standard"]: r for r in verdicts(0.04, 1.0, checkpoint_rmse_m=0.03)}
    assert by["asprs2014"]["class"] == "10-cm"  # 5-cm would need checkpoints <= 1.67 cm
    assert by["asprs2023"]["class"] == "10-cm"  # sqrt(4^2 + 3^2) = 5 cm; 2 x 3 cm > 5 cm


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (lambda: class_achieved(0.1, "asprs1991", 1.0), "standard"),
        (lambda: max_rmse("asprs1990", "4", 1.0), "class_name"),
        (lambda: max_rmse("asprs2014", "7-cm"), "class_name"),
        (lambda: class_achieved(-0.1, "asprs1990", 1.0), "rmse_m"),
        (lambda: class_achieved(float("nan"), "asprs1990", 1.0), "rmse_m"),
        (lambda: class_achieved(0.1, "asprs1990", 0.0), "contour_interval_m"),
        (lambda: class_achieved(0.1, "asprs1990", -1.0), "contour_interval_m"),
        (lambda: max_rmse("asprs1990", "1"), "contour_interval_m"),
        (lambda: max_rmse("asprs1990", "1", 1.0, feature="area"), "feature"),
        (lambda: finest_contour_interval(0.1, "asprs2023"), "standard"),
        (lambda: combined_rmse_with_checkpoints(0.1, -0.01), "checkpoint_rmse_m"),
        (lambda: min_checkpoints("asprs2014", -5), "area_km2"),
        (lambda: verdicts(0.1, float("inf")), "contour_interval_m"),
        (lambda: verdicts(0.1, 1.0, n_checkpoints=2.5), "n_checkpoints"),
    ],
)
def test_bad_inputs_name_the_field(call, field):
    with pytest.raises(InputError, match=field) as info:
        call()
    assert isinstance(info.value, ValueError) and "Fix:" in str(info.value)


def test_unknown_names_list_the_choices():
    with pytest.raises(InputError) as info:
        class_achieved(0.1, "asprs1991", 1.0)
    assert "asprs1991" in str(info.value) and "asprs2014" in str(info.value)
    with pytest.raises(InputError) as info:
        max_rmse("asprs1990", "4", 1.0)
    assert "'4'" in str(info.value) and "['1', '2', '3']" in str(info.value)
