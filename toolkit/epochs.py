"""A second epoch of the scenario's site: the same glacier after a known surface change,
surveyed again (the ``[change]`` table of the scenario, docs/change.md).

``epoch = 1`` is the site as it is. ``epoch = 2`` is the site after
:func:`terrain.second_epoch`: inside the glacier outline (:func:`terrain.default_outline`
of the site bounds with ``outline_margin``) the surface thins with elevation from
``max_thinning_m`` (lowest glacier cell) to ``min_thinning_m`` (highest), with
``n_features`` small ablation features, seeded by ``change_seed``; stable ground is
unchanged. That site is surveyed anew: the run's seed becomes ``seed + seed_offset`` after
the site is made (a random site keeps the scenario's seed), so the GPS bias, sensor noise,
texture, prior DEM error, checkpoints and GP subsets are fresh draws. Two runs of one
scenario, ``--epoch 1`` and ``--epoch 2``, are a change experiment with a known answer;
the epoch-2 folder also holds the outline (``glacier_outline.gpkg``) and the true change
(``true_change.tif``) for ``glacimap change``.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np

from terrain.atomic import atomic_path
from terrain.errors import bad_input

__all__ = [
    "CHANGE_FILES",
    "check_change",
    "epoch_truth",
    "glacier_outline",
    "survey_scenario",
    "true_change",
    "write_change_truth",
]

#: Files an epoch-2 run adds to its folder.
CHANGE_FILES = {"outline": "glacier_outline.gpkg", "true_change": "true_change.tif"}


def check_change(scenario: dict[str, Any]) -> None:
    """Validate the ``[change]`` table (values; the keys and types are checked by
    :func:`toolkit.config.load_scenario`).

    Raises
    ------
    InputError
        ``epoch`` not 1 or 2, a negative ``seed_offset`` or ``change_seed``, thinning not
        ``0 < min <= max``, ``outline_margin`` outside (0, 0.5), negative features or taper.
    """
    c = scenario["change"]
    if c["epoch"] not in (1, 2):
        raise bad_input("change.epoch", c["epoch"], "1 or 2", "2: the site after the change")
    for key in ("seed_offset", "change_seed", "n_features"):
        if c[key] < 0:
            raise bad_input(f"change.{key}", c[key], "an integer >= 0", "")
    if c["epoch"] == 2 and c["seed_offset"] == 0:
        raise bad_input(
            "change.seed_offset", 0, "> 0 (epoch 2 is a new survey)", "e.g. seed_offset = 2"
        )
    if not 0 < c["min_thinning_m"] <= c["max_thinning_m"]:
        raise bad_input(
            "change.min_thinning_m/max_thinning_m",
            (c["min_thinning_m"], c["max_thinning_m"]),
            "0 < min <= max (m)",
            "e.g. 0.5 and 3.0",
        )
    if not 0 < c["outline_margin"] < 0.5:
        raise bad_input("change.outline_margin", c["outline_margin"], "0 < margin < 0.5", "0.2")
    if c["taper_m"] < 0:
        raise bad_input("change.taper_m", c["taper_m"], ">= 0 (m)", "e.g. 20.0")


def glacier_outline(scenario: dict[str, Any]) -> Any:
    """The glacier outline of the scenario's site (shapely Polygon, site CRS)."""
    from terrain import default_outline

    bounds = tuple(float(b) for b in scenario["site"]["bounds"])
    return default_outline(bounds, float(scenario["change"]["outline_margin"]))


def true_change(scenario: dict[str, Any], truth: Any) -> Any:
    """The known change (m, negative = thinning) on the grid of the epoch-1 ``truth``."""
    from terrain import surface_change

    c = scenario["change"]
    return surface_change(
        truth,
        glacier_outline(scenario),
        seed=int(c["change_seed"]),
        min_thinning_m=float(c["min_thinning_m"]),
        max_thinning_m=float(c["max_thinning_m"]),
        n_features=int(c["n_features"]),
        taper_m=float(c["taper_m"]),
    )


def epoch_truth(scenario: dict[str, Any], truth: Any) -> Any:
    """``truth`` itself for epoch 1; for epoch 2 the site after :func:`true_change`
    (``xarray.DataArray``, north-up, attrs ``epoch``, ``change_seed``, ``surface_change``)."""
    if int(scenario["change"]["epoch"]) == 1:
        return truth
    from terrain.grid import north_up

    dh = true_change(scenario, truth)
    da = north_up(truth)
    out = da.copy(data=np.asarray(da.values, float) + dh.values)
    out.attrs.update(
        epoch=2,
        change_seed=int(scenario["change"]["change_seed"]),
        surface_change=dh.attrs["surface_change"],
    )
    return out


def survey_scenario(scenario: dict[str, Any]) -> dict[str, Any]:
    """The scenario the epoch is surveyed with: itself for epoch 1; for epoch 2 a copy with
    ``seed + seed_offset`` (call it after the site is made: a random site keeps the
    scenario's seed)."""
    if int(scenario["change"]["epoch"]) == 1:
        return scenario
    out = copy.deepcopy(scenario)
    out["seed"] = int(scenario["seed"]) + int(scenario["change"]["seed_offset"])
    return out


def write_change_truth(scenario: dict[str, Any], truth_epoch1: Any, out: Path) -> dict[str, Path]:
    """Epoch 2 only: ``glacier_outline.gpkg`` (one polygon, site CRS) and
    ``true_change.tif`` (COG, band ``dh``: the known change, m) in ``out``, atomically.
    Epoch 1: nothing (returns ``{}``)."""
    if int(scenario["change"]["epoch"]) == 1:
        return {}
    import pyogrio
    import shapely

    from terrain import Grid

    from .export import write_cog

    out = Path(out)
    dh = true_change(scenario, truth_epoch1)
    crs = Grid.from_dataarray(dh).crs.to_string()
    path = out / CHANGE_FILES["outline"]
    with atomic_path(path) as tmp:
        staged = tmp.with_suffix(".gpkg")  # GDAL will not write into mkstemp's empty file
        try:
            pyogrio.raw.write(
                staged,
                np.array([shapely.to_wkb(glacier_outline(scenario))], dtype=object),
                [],
                [],
                geometry_type="Polygon",
                crs=crs,
                driver="GPKG",
                layer="glacier_outline",
            )
            staged.replace(tmp)
        finally:
            staged.unlink(missing_ok=True)
    ds = dh.to_dataset(name="dh")
    ds.attrs = dict(dh.attrs)
    tif = write_cog(ds, out / CHANGE_FILES["true_change"], bands=[("dh", "true change")])
    return {"outline": path, "true_change": tif}
