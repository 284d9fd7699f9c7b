"""Products of a glacier-change run: the dh COG (with its 1-sigma band), the volume / mass
table (JSON + CSV) and a self-contained HTML report section (dh map, dh_std map, hypsometric
dh profile with 1-sigma, error budget), rendered from ``templates/change_report.html.j2``.

Every file is written atomically (:func:`terrain.atomic.atomic_path`).
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from terrain.atomic import atomic_path
from terrain.grid import Grid, north_up
from terrain.variogram import SphericalVariogram, covariance_sum
from terrain.volume import VolumeChange, outline_weights

from .report import _fmt, _plt, _png

__all__ = [
    "hypsometric_profile",
    "write_change_cog",
    "write_change_report",
    "write_volume_tables",
]

#: Band order of the change GeoTIFF: (description, long name); metres.
CHANGE_BANDS = (("dh", "elevation change after - before"), ("dh_std", "per-cell 1-sigma of dh"))


def write_change_cog(diff: Any, path: str | os.PathLike) -> Path:
    """The change map as a Cloud-Optimized GeoTIFF: bands ``dh`` and ``dh_std`` (float32, m,
    nodata NaN), the diff's provenance as dataset tags (:func:`toolkit.export.write_cog`)."""
    from .export import write_cog

    return write_cog(diff, path, bands=CHANGE_BANDS)


def write_volume_tables(vc: VolumeChange, json_path: Path, csv_path: Path, **extra: Any) -> None:
    """``volume.json`` (everything, with ``extra``) and ``volume.csv`` (quantity, value,
    1-sigma, unit; one row per budget source, and the ``mass_balance`` of ``extra``:
    :func:`terrain.mass_balance.mass_balance`)."""
    payload = {**vc.to_dict(), **extra}
    with atomic_path(json_path) as tmp:
        tmp.write_text(json.dumps(payload, indent=2, default=lambda o: np.asarray(o).tolist()))
    rows = [
        ("volume_change", vc.volume_m3, vc.volume_std_m3, "m3"),
        ("mean_dh", vc.mean_dh_m, vc.mean_dh_std_m, "m"),
        ("mass_change", vc.mass_kg, vc.mass_std_kg, "kg"),
        ("mass_change_gt", vc.mass_gt, vc.mass_std_kg / 1e12, "Gt"),
        ("area", vc.area_m2, 0.0, "m2"),
        ("density", *vc.density_kg_m3, "kg m-3"),
        ("independent_cells_sigma", "", vc.independent_std_m3, "m3"),
    ]
    mb = extra.get("mass_balance") or {}
    if mb:
        rows.append(("specific_mass_balance", mb["specific_mwe"], mb["specific_std_mwe"], "m w.e."))
    if "rate_mwe_a" in mb:
        rows.append(("mass_balance_rate", mb["rate_mwe_a"], mb["rate_std_mwe_a"], "m w.e. a-1"))
        rows.append(("dh_dt", mb["dhdt_m_a"], mb["dhdt_std_m_a"], "m a-1"))
        rows.append(("period", mb["years"], 0.0, "a"))
    rows += [(f"budget_{k}", "", v, "m3") for k, v in vc.budget_m3.items()]
    with atomic_path(csv_path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["quantity", "value", "std", "unit"])
        w.writerows(rows)


def band_sigma_from(vc: VolumeChange, grid: Grid) -> Callable[[np.ndarray], float] | None:
    """1-sigma of a band's mean dh from the variogram of ``vc`` (None for other methods)."""
    v = vc.details.get("variogram")
    if not v:
        return None
    vario = SphericalVariogram(v["nugget_m2"], tuple(v["sills_m2"]), tuple(v["ranges_m"]))

    def sigma(weights: np.ndarray) -> float:
        var = covariance_sum(weights, grid.resolution, vario.correlated_covariance)
        var += vario.nugget * float(np.sum(weights**2))
        return float(np.sqrt(var) / weights.sum())

    return sigma


def hypsometric_profile(
    diff: Any,
    outline: Any,
    band_m: float | None = None,
    band_sigma: Callable[[np.ndarray], float] | None = None,
) -> list[dict[str, float]]:
    """Mean dh per elevation band of the *before* surface inside ``outline``.

    Returns rows ``{z_lo, z_hi, n_cells, mean_dh, sigma}``; ``sigma`` from ``band_sigma``
    (the band's cell-area weights -> 1-sigma of its mean dh), else the per-cell ``dh_std``
    averaged (fully correlated within a band: an upper bound).
    """
    diff = north_up(diff)
    grid = Grid.from_dataarray(diff)
    W = outline_weights(grid, outline)
    z = np.asarray(diff["elevation_before"].values, float)
    dh = np.asarray(diff["dh"].values, float)
    std = np.asarray(diff["dh_std"].values, float)
    ok = (W > 0) & np.isfinite(z) & np.isfinite(dh)
    if not ok.any():
        return []
    lo, hi = float(z[ok].min()), float(z[ok].max())
    band_m = band_m or max((hi - lo) / 8, 1e-6)
    edges = np.arange(lo, hi + band_m, band_m)
    rows = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        m = ok & (z >= a) & (z < b if b < edges[-1] else z <= b)
        if m.sum() < 2:
            continue
        w = np.where(m, W, 0.0)
        s = band_sigma(w) if band_sigma else float(np.nanmean(std[m]))
        mean = float(np.sum(w[m] * dh[m]) / w[m].sum())
        rows.append({"z_lo": a, "z_hi": b, "n_cells": int(m.sum()), "mean_dh": mean, "sigma": s})
    return rows


def _map(diff, name: str, title: str, cmap: str, outline, centred: bool) -> dict[str, str]:
    plt = _plt()
    grid = Grid.from_dataarray(diff)
    w, s, e, n = grid.bounds
    v = np.asarray(diff[name].values, float)
    fig, ax = plt.subplots(figsize=(5.2, 4.4))
    lim = float(np.nanmax(np.abs(v))) if np.isfinite(v).any() else 1.0
    kw = {"vmin": -lim, "vmax": lim} if centred else {}
    im = ax.imshow(v, extent=(0, e - w, 0, n - s), cmap=cmap, origin="upper", **kw)
    fig.colorbar(im, ax=ax, label=f"{name} [m]")
    for g in getattr(outline, "geoms", [outline]):
        x, y = g.exterior.xy
        ax.plot(np.asarray(x) - w, np.asarray(y) - s, "k-", lw=1)
    ax.set(title=title, xlabel="easting from SW corner [m]", ylabel="northing [m]")
    ax.set_aspect("equal")
    fig.tight_layout()
    caption = f"{title}; glacier outline in black; {grid.crs.to_string()}."
    return {"id": f"fig-{name}", "src": _png(fig), "caption": caption}


def _hypso_fig(rows: list[dict[str, float]]) -> dict[str, str]:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.2, 4.4))
    if rows:
        zc = [(r["z_lo"] + r["z_hi"]) / 2 for r in rows]
        m = [r["mean_dh"] for r in rows]
        s = [r["sigma"] for r in rows]
        ax.errorbar(m, zc, xerr=np.multiply(s, 1.96), fmt="o-", capsize=3)
    ax.axvline(0, color="0.5", lw=0.8)
    ax.set(xlabel="mean dh [m] (95 % bars)", ylabel="elevation band (before) [m]")
    ax.set_title("hypsometric dh profile")
    fig.tight_layout()
    cap = "Mean dh per elevation band of the earlier surface inside the outline, 1.96 sigma bars."
    return {"id": "fig-hypsometry", "src": _png(fig), "caption": cap}


def epoch_breaklines(
    before_attrs: Mapping[str, Any], after_attrs: Mapping[str, Any], models: Any = None
) -> dict:
    """The breaklines each epoch's map was fitted with (:func:`toolkit.breakline_record.
    breakline_rows` of each product's attributes, vertices left out) and, per line of the
    before map, its step's change (``step_changes``: :func:`toolkit.breakline_record.
    step_changes`, a change with its 1-sigma or the reason none is given; with both maps'
    rebuilt GPs, ``models``, read at one shared width: :func:`toolkit.breakline_record.
    at_shared_width`); ``{}`` when neither has lines."""
    from .breakline_record import at_shared_width, breakline_rows, step_changes

    rows = {"before": breakline_rows(before_attrs), "after": breakline_rows(after_attrs)}
    if not rows["before"] and not rows["after"]:
        return {}
    out: dict[str, Any] = {
        k: [{n: v for n, v in r.items() if n != "vertices"} for r in rs] for k, rs in rows.items()
    }
    changes = step_changes(rows["before"], rows["after"])
    out["step_changes"] = at_shared_width(changes, rows["before"], rows["after"], models)
    return out


def write_change_report(
    path: str | os.PathLike,
    diff: Any,
    vc: VolumeChange,
    outline: Any,
    profile: list[dict[str, float]] | None = None,
    title: str = "glacimap glacier change",
    breaklines: Mapping[str, Any] | None = None,
    balance: Mapping[str, Any] | None = None,
) -> Path:
    """Write the HTML change report (self-contained: figures are data URIs); ``breaklines``
    (:func:`epoch_breaklines`) adds the lines each epoch's map was fitted with, ``balance``
    (:func:`terrain.mass_balance.mass_balance`) the specific mass balance."""
    import jinja2

    diff = north_up(diff)
    grid = Grid.from_dataarray(diff)
    if profile is None:
        profile = hypsometric_profile(diff, outline, band_sigma=band_sigma_from(vc, grid))
    figures = [
        _map(diff, "dh", "elevation change dh", "RdBu", outline, True),
        _map(diff, "dh_std", "per-cell 1-sigma of dh", "magma", outline, False),
        _hypso_fig(profile),
    ]
    coreg = diff.attrs.get("coregistration", "none")
    coreg = json.loads(coreg) if coreg not in ("none", "", None) else None
    budget = sorted(vc.budget_m3.items(), key=lambda kv: -kv[1])
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("toolkit", "templates"),
        autoescape=True,
        undefined=jinja2.ChainableUndefined,
    )
    env.filters["fmt"] = _fmt
    skip = ("crs_wkt", "transform", "coregistration")
    html = env.get_template("change_report.html.j2").render(
        title=title,
        grid=grid,
        attrs=diff.attrs,
        vc=vc,
        balance=balance or {},
        budget=budget,
        total_var=max(sum(v * v for _, v in budget), 1e-300),
        coreg=coreg,
        figures=figures,
        provenance={k: v for k, v in diff.attrs.items() if k not in skip},
        breaklines=breaklines or {},
    )
    target = Path(path)
    with atomic_path(target) as tmp:
        tmp.write_text(html, encoding="utf-8")
    return target
