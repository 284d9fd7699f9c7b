"""Settings of :class:`terrain.TerrainGP`, checked in one place before a fit.

Every bad value raises :class:`terrain.errors.InputError` naming the setting, the value,
what it should be and, where one exists, the fix (rasterio's habit: errors in one place).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .anisotropy import as_anisotropy
from .errors import bad_input
from .kernel_search import candidate_names
from .samples import ElevationSamples
from .tiled import TileSpec

if TYPE_CHECKING:
    from .gp import TerrainGP

__all__ = ["check_samples", "check_settings"]


def check_samples(samples: object) -> None:
    """Raise ``InputError`` unless ``samples`` is an ``ElevationSamples`` of 3 or more."""
    if not isinstance(samples, ElevationSamples):
        raise bad_input(
            "samples",
            type(samples).__name__,
            "terrain.ElevationSamples",
            "wrap arrays with ElevationSamples(xy, z, z_var)",
        )
    if samples.n < 3:
        raise bad_input(
            "samples",
            f"{samples.n} samples",
            "at least 3 samples to fit a surface",
            "collect more data or widen the selection",
        )


def check_settings(gp: TerrainGP) -> None:
    """Raise ``InputError`` for the first setting of ``gp`` that cannot work."""
    if gp._searches_kernel:
        candidate_names(gp.kernel)
        if not gp.optimize and gp.kernel != "auto":
            raise bad_input(
                "optimize",
                False,
                f"True when kernel={gp.kernel!r} (the kernel is chosen by fitting)",
                "pass a Kernel object to keep its hyperparameters fixed",
            )
    if not (np.isfinite(gp.nugget) and gp.nugget >= 0):
        raise bad_input("nugget", gp.nugget, "a variance >= 0 in m^2", "e.g. nugget=0.01")
    if gp.fit_nugget:
        lo, hi = gp.nugget_bounds
        if not (0 < lo <= max(gp.nugget, lo) <= hi):
            raise bad_input(
                "nugget_bounds",
                gp.nugget_bounds,
                "0 < low <= nugget <= high",
                'widen the bounds or pass nugget_bounds="fixed"',
            )
    elif gp.nugget_bounds != "fixed":
        raise bad_input("nugget_bounds", gp.nugget_bounds, '(low, high) or "fixed"', "")
    if int(gp.n_restarts) < 0:
        raise bad_input("n_restarts", gp.n_restarts, ">= 0", "e.g. n_restarts=2")
    if gp.max_fit_samples is not None and int(gp.max_fit_samples) < 3:
        raise bad_input("max_fit_samples", gp.max_fit_samples, ">= 3 or None", "")
    if gp.method not in ("auto", "exact", "tiled"):
        raise bad_input(
            "method",
            gp.method,
            '"auto", "exact" or "tiled"',
            '"auto" takes exact up to exact_max_samples and tiled above',
        )
    as_anisotropy(gp.anisotropy)
    if gp.tiles is not None and not isinstance(gp.tiles, TileSpec):
        raise bad_input("tiles", gp.tiles, "a terrain.tiled.TileSpec or None", "")
    if int(gp.exact_max_samples) < 3:
        raise bad_input("exact_max_samples", gp.exact_max_samples, ">= 3", "")
    if gp.chunk_size is not None and int(gp.chunk_size) < 1:
        raise bad_input("chunk_size", gp.chunk_size, ">= 1 or None", "")
    if gp.local_amplitude not in (True, False, "auto"):
        raise bad_input(
            "local_amplitude",
            gp.local_amplitude,
            'True, False or "auto"',
            '"auto" (default) uses it whenever the tiled GP is fitted',
        )
    if gp._amplitude_always and gp.method == "exact":
        fix = 'use method="tiled" (or "auto"), or local_amplitude=False'
        raise bad_input("local_amplitude", True, "the tiled GP", fix)
    if not (np.isfinite(gp.amplitude_prior_sd) and gp.amplitude_prior_sd > 0):
        raise bad_input("amplitude_prior_sd", gp.amplitude_prior_sd, "> 0", "e.g. 1.0")
