"""The per-line settings of :class:`terrain.BreaklineMean` (each step's ``width`` and
``taper``): read from what a user or a product gives, and written back in its repr."""

from __future__ import annotations

from numbers import Real
from typing import Any

import numpy as np

from .errors import bad_input

__all__ = ["per_line", "read_ends", "setting_repr"]


def _positive(value: Any) -> bool:
    return isinstance(value, Real) and not isinstance(value, bool) and 0 < value < np.inf


def per_line(
    value: Any, name: str, n: int, example: str, none_ok: bool = False
) -> tuple[Any, tuple | None]:
    """``value`` of a per-line setting (``width``, ``taper``): ``"auto"``, a positive number
    (m) for every line, or one per line (what a fit chose, given back; ``None`` for a line
    it does not apply to where ``none_ok``); ``(setting, fitted)``."""
    if isinstance(value, str) and value == "auto":
        return "auto", None
    if _positive(value):
        return float(value), (float(value),) * n
    if (
        np.ndim(value) == 1
        and len(value) == n
        and all(_positive(v) or (none_ok and v is None) for v in value)
    ):
        out = tuple(None if v is None else float(v) for v in value)
        return out, out
    raise bad_input(
        name,
        value,
        f'"auto", a positive {name} in m, or {n} of them (one per line)',
        f"e.g. {name}={example}",
    )


def setting_repr(name: str, setting: Any, fitted: Any) -> str:
    """``width=...`` or ``taper=...`` as a repr shows it (what was chosen, after "auto")."""

    def fmt(values: Any) -> str:
        return ", ".join("-" if v is None else f"{v:g}" for v in values)

    if isinstance(setting, tuple):
        return f"{name}=({fmt(setting)}) m"
    if setting != "auto":
        return f"{name}={setting:g} m"
    return f"{name}='auto'" + (f" ({fmt(fitted)} m)" if fitted is not None else "")


def read_ends(value: Any, n: int) -> Any:
    """``ends`` of a ``BreaklineMean`` with ``n`` lines: ``"auto"`` (open where inside the
    fitted samples' box), ``"open"`` (every end), or per line a pair of booleans (first,
    last vertex; what a fit decided, given back); anything else an ``InputError``."""
    if isinstance(value, str) and value in ("auto", "open"):
        return value
    try:
        pairs = tuple((bool(a), bool(b)) for a, b in value)
        ok = len(pairs) == n and all(isinstance(e, bool | np.bool_) for pair in value for e in pair)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise bad_input(
            "ends",
            value,
            f'"auto", "open", or {n} pairs of booleans (first, last vertex open)',
            'e.g. ends="auto": open where the line stops inside the survey',
        )
    return pairs
