"""A new unfitted estimator with another's constructor parameters (scikit-learn's
``clone``, without its dependency), and the fitted hyperparameters a held-out check holds
fixed (:func:`terrain.cross_validate`)."""

from __future__ import annotations

import inspect
from typing import Any

__all__ = ["clone", "fixed_overrides", "is_fitted"]

#: Constructor settings that hold a fitted model's hyperparameters fixed in a refit.
_HYPER_FIXED = {"nugget_bounds": "fixed", "optimize": False}


def is_fitted(est: Any) -> bool:
    """Whether ``est`` has fitted attributes (a name ending in "_", scikit-learn's rule)."""
    return any(k.endswith("_") and not k.startswith("__") for k in vars(est))


def clone(est: Any, **overrides: Any) -> Any:
    """A new unfitted estimator with ``est``'s constructor parameters (scikit-learn style):
    names from ``inspect.signature(type(est).__init__)``, values from ``getattr(est, name)``;
    ``overrides`` that the constructor does not take are ignored."""
    params = [
        p
        for p in inspect.signature(type(est).__init__).parameters.values()
        if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
    ]
    kwargs = {p.name: getattr(est, p.name) for p in params}
    kwargs.update({k: v for k, v in overrides.items() if k in kwargs})
    return type(est)(**kwargs)


def fixed_overrides(est: Any) -> dict[str, Any]:
    """The fitted model's kernel, nugget and anisotropy, held fixed, and the GP it chose
    (exact or tiled, with or without per-tile amplitudes), so that a fold with fewer samples
    than the map is not scored with another model (``local_amplitude="auto"`` turns on from
    1,000); a ``BreaklineMean``'s open ends held too."""
    out = dict(_HYPER_FIXED)
    for name in ("kernel", "nugget", "method", "local_amplitude", "anisotropy"):
        if hasattr(est, name + "_"):
            out[name] = getattr(est, name + "_")
    # a breakline's open ends are the map's, whatever box a fold's samples leave
    mean, ends = (
        getattr(est, "mean", None),
        getattr(getattr(est, "mean_", None), "open_ends_", None),
    )
    if hasattr(mean, "with_ends") and ends is not None:
        out["mean"] = mean.with_ends(ends)
    return out
