"""Every error and warning glacimap raises, in one place (rasterio style).

Errors subclass the builtins (``ValueError``, ``OSError``, ``ArithmeticError``) so that
callers can catch them either way. Each message says which field was wrong, what value it
had, and what to do about it; :func:`bad_input` builds such messages uniformly.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = [
    "CRSMismatchError",
    "DegenerateFitWarning",
    "DuplicateLocationError",
    "GlacimapError",
    "InputError",
    "JitterWarning",
    "NotFittedError",
    "NumericalError",
    "TilingWarning",
    "bad_input",
    "positive_number",
]


class GlacimapError(Exception):
    """Base class of every error glacimap raises on purpose."""


class InputError(GlacimapError, ValueError):
    """Bad input: names the field, the value received and the fix."""


class CRSMismatchError(InputError):
    """Two georeferenced objects are in different coordinate reference systems."""


class DuplicateLocationError(InputError):
    """Samples share a location but disagree beyond their stated noise."""


class NotFittedError(GlacimapError, AttributeError):
    """An estimator was used before ``fit``."""


class NumericalError(GlacimapError, ArithmeticError):
    """A matrix stayed non positive definite even after the largest allowed jitter."""


class JitterWarning(RuntimeWarning):
    """A kernel matrix needed diagonal jitter to factor; the message says how much."""


class DegenerateFitWarning(RuntimeWarning):
    """A fitted GP is degenerate: its length scale is below the sample spacing, or its map
    reverts to the prior mean almost everywhere (flat map, uniform 1-sigma)."""


class TilingWarning(RuntimeWarning):
    """A tiled GP cannot carry a long-scale kernel component across gaps wider than its halo."""


def _short(value: Any, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def bad_input(
    field: str, value: Any, expected: str, fix: str, cls: type[InputError] = InputError
) -> InputError:
    """Build an :class:`InputError` with the house message shape.

    Parameters
    ----------
    field : str
        Name of the argument or attribute that was wrong (``"z_var"``, ``"grid.shape"``).
    value : object
        What was received (shortened in the message).
    expected : str
        What was expected, in words.
    fix : str
        What the caller should do.
    cls : type, optional
        The subclass to instantiate.
    """
    return cls(f"{field}: expected {expected}, got {_short(value)}. Fix: {fix}")


def positive_number(field: str, value: Any, fix: str, allow_zero: bool = False) -> float:
    """``float(value)`` when it is finite and > 0 (>= 0 with ``allow_zero``); otherwise an
    :class:`InputError` naming ``field``, the value and ``fix``."""
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise bad_input(field, value, "a number", fix) from exc
    if not (math.isfinite(v) and (v >= 0 if allow_zero else v > 0)):
        want = "a finite number >= 0" if allow_zero else "a finite number > 0"
        raise bad_input(field, value, want, fix)
    return v
