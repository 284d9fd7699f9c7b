"""Inner loops compiled with Numba, each built once, on first use.

Some loops here are a few arithmetic operations on each of ~1e9 matrix entries (a kernel
table lookup) or on each of ~1e5 tiny matrices (a Vecchia conditional). In NumPy they cost
one pass over memory per operation, or one LAPACK call per 11 x 11 matrix; compiled, they
run as one loop each that releases the GIL, so the tiles' and candidates' threads run side
by side (docs/terrain.md "Performance notes").

Each loop has a NumPy twin beside it, which the tests compare it with and which runs where
Numba is not installed (a platform it has no wheel for). Compiled code is cached on disk by
Numba (``cache=True``): a new process loads it in ~0.5 s instead of compiling.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

__all__ = ["compiled"]

_LOCK = threading.Lock()
_BUILT: dict[str, Any] = {}


def compiled(name: str, build: Callable[[Any], Callable]) -> Callable | None:
    """The loop ``build(numba)`` returns, built once per process under ``name``; ``None``
    where Numba cannot be imported (the caller then runs its NumPy twin)."""
    if name not in _BUILT:
        with _LOCK:
            if name not in _BUILT:
                try:
                    import numba
                except ImportError:  # pragma: no cover - a dependency; for odd platforms
                    _BUILT[name] = None
                else:
                    _BUILT[name] = build(numba)
    return _BUILT[name]
