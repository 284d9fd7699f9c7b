"""Two glacimap products as the inputs of ``glacimap change``, with their GPs rebuilt.

A product folder of ``glacimap run`` / ``process`` / ``reconstruct`` holds the map
(``product.nc``: ``elevation``, ``elevation_std`` and, in its attributes, the fitted
``kernel``, ``hyperparameters`` (with the nugget), ``mean_function``, ``method``, ``seed``
and ``shared_vertical_offset_std_m``) and, for ``run`` / ``process``, the samples it was
made from (``samples.csv``). That is all the exact-structure 1-sigma of
:func:`terrain.volume_change` needs: :func:`rebuild_gp` refits a :class:`terrain.TerrainGP`
on the samples *at the recorded hyperparameters* (no optimisation; the mean's coefficients
come out of the same GLS on the same samples) and checks that it reproduces the product's
elevation before it is used. When anything is missing or does not match, the GP route is
not taken and the reason is returned, for the output to state (docs/change.md).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from terrain.errors import InputError, bad_input

__all__ = ["ProductInput", "kernel_from_provenance", "locate_product", "rebuild_gp"]

#: Largest |rebuilt mean - product elevation| (m) at the checked cells for the GP route.
REPRODUCE_TOL_M = 1e-3
#: Cells (seeded) at which the rebuilt GP's mean is compared with the product.
N_CHECK_CELLS = 400

#: One kernel term of a product's ``kernel`` repr (a :class:`terrain.microscale.Microscale`
#: part is a Matérn 3/2 that the tiles are sized without: read back as one).
_PART = re.compile(r"(SquaredExponential|Matern|Microscale)\(([^)]*)\)")


@dataclass(frozen=True)
class ProductInput:
    """Where one epoch's map, samples and prior DEM are.

    Attributes
    ----------
    raster : Path
        The map read (a product NetCDF or a GeoTIFF).
    samples : Path or None
        The samples it was made from (``--samples-*``, or ``samples.csv`` beside the map).
    folder : Path or None
        The product folder, when one was given (or the map's own folder).
    """

    raster: Path
    samples: Path | None
    folder: Path | None


def locate_product(path: Path, samples: Path | None, field: str) -> ProductInput:
    """The map and samples of ``path``: a product folder (``product.nc`` inside, and
    ``samples.csv`` when present) or a raster file (``samples.csv`` beside it is used when
    present). An explicit ``samples`` file must exist.

    Raises
    ------
    InputError
        A folder without ``product.nc``; a missing ``samples`` file.
    """
    path = Path(path)
    if path.is_dir():
        raster = path / "product.nc"
        if not raster.is_file():
            raise bad_input(
                field,
                str(path),
                "a glacimap product folder (with product.nc) or a NetCDF / GeoTIFF DEM",
                "pass the output folder of glacimap run / process / reconstruct, or a file",
            )
        folder = path
    else:
        raster, folder = path, path.parent
    if samples is not None:
        if not Path(samples).is_file():
            raise bad_input(
                f"--samples-{field.lower()}", str(samples), "an existing samples CSV", ""
            )
        return ProductInput(raster, Path(samples), folder)
    beside = folder / "samples.csv"
    return ProductInput(raster, beside if beside.is_file() else None, folder)


def kernel_from_provenance(kernel_repr: str, hyperparameters: str | dict) -> Any:
    """The fitted kernel of a product: its families from ``kernel`` (the ``repr`` that
    :meth:`TerrainGP.provenance` writes, e.g. ``Matern(...) + SquaredExponential(...)``) and
    its exact values from ``hyperparameters`` (JSON: ``variance``, ``lengthscale`` or
    ``lengthscale_x``/``_y``, prefixed ``k1.``, ``k2.`` ... for a sum).

    Raises
    ------
    InputError
        A family glacimap does not have, or hyperparameters that do not match the families.
    """
    from terrain.kernels import Matern, SquaredExponential, SumKernel
    from terrain.microscale import Microscale

    hyper = json.loads(hyperparameters) if isinstance(hyperparameters, str) else hyperparameters
    parts = _PART.findall(str(kernel_repr))
    if not parts:
        raise bad_input(
            "product kernel", kernel_repr, "SquaredExponential / Matern / Microscale terms", ""
        )
    built = []
    for i, (family, args) in enumerate(parts, start=1):
        prefix = f"k{i}." if len(parts) > 1 else ""
        try:
            var = float(hyper[f"{prefix}variance"])
            if f"{prefix}lengthscale" in hyper:
                ls: Any = float(hyper[f"{prefix}lengthscale"])
            else:
                ls = (
                    float(hyper[f"{prefix}lengthscale_x"]),
                    float(hyper[f"{prefix}lengthscale_y"]),
                )
        except (KeyError, TypeError, ValueError) as exc:
            raise bad_input(
                "product hyperparameters", hyper, f"the values of {kernel_repr}", str(exc)
            ) from exc
        if family == "Microscale":
            built.append(Microscale(var, ls))
        elif family == "Matern":
            nu = re.search(r"nu=([0-9.]+)", args)
            built.append(Matern(var, ls, nu=float(nu.group(1)) if nu else 1.5))
        else:
            built.append(SquaredExponential(var, ls))
    return built[0] if len(built) == 1 else SumKernel(tuple(built))


def _prior_path(mean_repr: str, folder: Path | None, given: Path | None) -> Path:
    """The prior DEM of a ``RasterMean``: ``given``, else the path it recorded (as is, then
    relative to the product folder, then ``field/<name>`` or ``<name>`` in that folder)."""
    if given is not None:
        return Path(given)
    m = re.match(r"RasterMean\('([^']*)'", mean_repr)
    if m is None:
        raise InputError(f"the prior DEM's path is not recorded in {mean_repr[:80]!r}")
    rec = Path(m.group(1))
    tries = [rec]
    if folder is not None:
        tries += [folder / rec, folder / "field" / rec.name, folder / rec.name]
    tries = list(dict.fromkeys(tries))  # each place once in the message
    for p in tries:
        if p.is_file():
            return p
    raise InputError(
        f"the prior DEM {rec} (the map's mean) was not found (tried "
        f"{', '.join(str(t) for t in tries)}); pass --prior-before/--prior-after"
    )


def _mean_from_provenance(
    mean_repr: str, folder: Path | None, prior: Path | None, breaklines: str = ""
) -> Any:
    from terrain import BreaklineMean, RasterMean

    if mean_repr.startswith("BreaklineMean("):  # the base's repr follows "base="
        if not breaklines:
            raise InputError("the map's breaklines are not recorded (a product before 0.36.0)")
        feature = json.loads(breaklines)
        base = _mean_from_provenance(mean_repr.split("base=", 1)[1], folder, prior)
        lines = [np.asarray(c, float) for c in feature["geometry"]["coordinates"]]
        shape = feature["properties"]  # tapers: None for a line run on at both ends
        tapers = shape.get("tapers_m") or "auto"  # not recorded before 0.37.0: none open
        ends = shape.get("open_ends") or "auto"
        out = BreaklineMean(lines, base=base, width=shape["widths_m"], taper=tapers, ends=ends)
        if shape.get("widths_sd_m") is not None:  # chosen by the map's evidence: the fit
            out.widths_sd_ = tuple(shape["widths_sd_m"])  # derives their 1-sigma again
        return out
    if mean_repr.startswith("ConstantMean(value=None"):
        return "constant"
    if mean_repr.startswith("RasterMean("):
        resampling = re.search(r"resampling='(\w+)'", mean_repr)
        cells = re.search(r"cells=\((\d+), (\d+)\)", mean_repr)
        return RasterMean(
            str(_prior_path(mean_repr, folder, prior)),
            resampling=resampling.group(1) if resampling else "bilinear",
            cells=(int(cells.group(1)), int(cells.group(2))) if cells else None,
        )
    raise InputError(f"mean {mean_repr[:60]!r} cannot be rebuilt from a file (not a fitted "
                     "constant, a RasterMean or a BreaklineMean)")  # fmt: skip


def rebuild_gp(
    product: Any, where: ProductInput, prior: Path | None = None, seed: int = 0
) -> tuple[Any, str]:
    """The product's fitted GP, rebuilt from its samples at its recorded hyperparameters.

    Parameters
    ----------
    product : xarray.Dataset
        The map (``elevation`` and the provenance attributes of :meth:`TerrainGP.provenance`).
    where : ProductInput
        Its samples (None: no GP) and folder (to find the prior DEM).
    prior : Path, optional
        The prior DEM, when the path the product recorded is not where it was.
    seed : int
        Seed of the cells checked.

    Returns
    -------
    (TerrainGP or None, str)
        The refitted GP and a note on how it matches the product (max |difference| of the
        mean at :data:`N_CHECK_CELLS` seeded cells), or None and the reason the GP route is
        not possible. A GP whose mean differs from the product's elevation by more than
        :data:`REPRODUCE_TOL_M` is not returned.
    """
    from terrain import Anisotropy, Grid, TerrainGP
    from terrain.grid import north_up

    from .certify_io import read_checkpoints
    from .samples_io import read_samples

    if where.samples is None:
        return None, f"no samples.csv beside {where.raster} (pass --samples-*)"
    attrs = product.attrs
    missing = [k for k in ("kernel", "hyperparameters", "mean_function") if k not in attrs]
    if missing:
        return None, f"{where.raster} does not record {missing} (not a glacimap GP product)"
    try:
        kernel = kernel_from_provenance(attrs["kernel"], attrs["hyperparameters"])
        nugget = float(json.loads(attrs["hyperparameters"])["nugget"])
        geometry = json.loads(attrs.get("anisotropy", "{}"))  # none recorded: isotropic
        anisotropy = Anisotropy(geometry.get("azimuth_deg", 0.0), geometry.get("ratio", 1.0))
        mean = _mean_from_provenance(
            str(attrs["mean_function"]), where.folder, prior, str(attrs.get("breaklines", ""))
        )
        grid = Grid.from_dataarray(north_up(product))
        # a CSV that states no CRS (reconstruct took --crs) is read in the map's: the map
        # was made in its samples' CRS, and a wrong file fails the reproduction check below
        stated = read_checkpoints(where.samples).crs
        samples = read_samples(where.samples, crs=stated or grid.crs).samples
    except (InputError, KeyError, TypeError, ValueError) as exc:
        return None, f"{where.raster}: {exc}"
    if not samples.crs.equals(grid.crs, ignore_axis_order=True):
        return None, f"{where.samples} is not in the map's CRS ({grid.crs.to_string()})"
    if hasattr(mean, "for_grid"):  # as toolkit.stages.reconstruct_stage: cells over the map
        mean.for_grid(grid)
    exact = str(attrs.get("method", "exact")).startswith("exact")
    gp = TerrainGP(
        kernel=kernel,
        anisotropy=anisotropy,
        mean=mean,
        nugget=nugget,
        nugget_bounds="fixed",
        optimize=False,
        method="exact" if exact else "tiled",
        seed=int(attrs.get("seed", seed)),
    ).fit(samples)
    z = np.asarray(north_up(product)["elevation"].values, float).ravel()
    ok = np.flatnonzero(np.isfinite(z))
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(ok, size=min(N_CHECK_CELLS, ok.size), replace=False))
    diff = float(np.max(np.abs(gp.predict(grid.xy()[idx]) - z[idx])))
    note = (
        f"rebuilt from {samples.n} samples at the recorded {gp.kernel_!r}, nugget "
        f"{nugget:.3g} m^2: mean within {diff:.1e} m of the product at {idx.size} cells"
    )
    if stated is None:
        note += f" ({where.samples.name} states no CRS: read in the map's, {grid.crs.to_string()})"
    if not diff <= REPRODUCE_TOL_M:
        return None, f"the GP rebuilt from {where.samples} does not reproduce the map ({note})"
    return gp, note
