"""Choosing the kernel family by evidence: the log marginal likelihood (Eq 9).

Real terrain is often rougher than the squared exponential (Eq 1) assumes; whether a Matérn
or a sum of scales fits a site better is a question for the data, not a default.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from .errors import bad_input
from .gp import TerrainGP
from .kernels import Kernel, SumKernel
from .samples import ElevationSamples

__all__ = ["compare_kernels"]


def compare_kernels(
    samples: ElevationSamples,
    kernels: Mapping[str, Kernel | SumKernel],
    **gp_kwargs: Any,
) -> list[dict[str, Any]]:
    """Fit one :class:`TerrainGP` per candidate kernel and rank them by evidence.

    Parameters
    ----------
    samples : ElevationSamples
        The data every candidate is fitted to.
    kernels : mapping of name to kernel
        Candidates with their initial hyperparameters and bounds.
    **gp_kwargs
        Passed to every :class:`TerrainGP` (mean, nugget, seed, max_fit_samples...).

    Returns
    -------
    list of dict
        One row per kernel, best first: ``name``, ``kernel`` (fitted, repr), ``lml``
        (Eq 9 at the fitted hyperparameters, nats), ``n_params``, ``bic``
        (``-2 lml + p log n``, lower is better) and ``delta_lml`` (to the best).
    """
    if not kernels:
        raise bad_input("kernels", kernels, "at least one candidate kernel", "")
    rows = []
    for name, kernel in kernels.items():
        gp = TerrainGP(kernel=kernel, **gp_kwargs).fit(samples)
        p = gp.kernel_.n_params + int(gp.fit_nugget)
        lml = gp.log_marginal_likelihood_value_
        rows.append(
            {
                "name": name,
                "kernel": repr(gp.kernel_),
                "lml": lml,
                "n_params": p,
                "bic": -2.0 * lml + p * np.log(samples.n),
                "nugget": gp.nugget_,
            }
        )
    rows.sort(key=lambda r: -r["lml"])
    for r in rows:
        r["delta_lml"] = r["lml"] - rows[0]["lml"]
    return rows
