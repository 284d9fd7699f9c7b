"""Large temporary arrays without a page fault per page: glibc's malloc told to reuse memory.

numpy takes every array above glibc's mmap threshold from ``mmap`` and gives it back with
``munmap``, so a fresh array costs one page fault per 4 KiB page when it is first written.
The threshold starts at 128 KiB and glibc raises it only when such a block is freed, to that
block's size, so the first pass of a computation through arrays of new sizes (a fit's kernel
matrices, Vecchia blocks and GLS solves) pays the page faults on every array. On the
machines measured here (a 2-core virtual machine) page faults are slow: the first fit of
50,000 samples in a process took 5.0-5.4 s, the second 3.0-3.3 s (docs/terrain.md
"Performance notes").

:func:`keep_freed_memory` fixes the threshold at 32 MiB (glibc's largest) and keeps up to
128 MiB of freed memory for reuse instead of returning it to the system. Measured on three
real-DEM sites (50,000 samples, a fresh process each): the first fit took 2.4-3.3 s against
3.5-5.4 s, at ~140 MB more peak resident memory for the fit and a 600 x 600 map (478-488 MB
against 325-347 MB; keeping 32 MiB: 342-354 MB, the fit ~0.4 s slower). The values are the
same bits: only where memory comes from changes. It runs once per process, on glibc only,
and not at all with ``GLACIMAP_MALLOC=default``.
"""

from __future__ import annotations

import ctypes
import functools
import os

__all__ = ["MMAP_THRESHOLD", "TRIM_THRESHOLD", "keep_freed_memory"]

#: Arrays up to this size (bytes) come from the heap and are reused: glibc's largest value
#: for M_MMAP_THRESHOLD on 64-bit (HEAP_MAX_SIZE / 2).
MMAP_THRESHOLD = 32 * 1024 * 1024
#: Freed memory kept at the top of the heap before it is returned to the system, bytes.
TRIM_THRESHOLD = 128 * 1024 * 1024
_M_TRIM_THRESHOLD = -1  # glibc <malloc.h>
_M_MMAP_THRESHOLD = -3
#: Environment variable that turns the tuning off (value ``default``).
ENV = "GLACIMAP_MALLOC"


@functools.cache
def keep_freed_memory() -> bool:
    """Set glibc's mmap and trim thresholds once per process (module docstring).

    Returns
    -------
    bool
        Whether both were set: ``False`` off glibc (macOS, Windows, musl), or when the
        environment variable ``GLACIMAP_MALLOC`` is ``default``.
    """
    if os.environ.get(ENV, "").strip().lower() == "default":
        return False
    try:
        # The process's own symbols (dlopen(NULL)): libc's, with no ldconfig subprocess.
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
        # glibc only: other libcs differ in mallopt's options (or have none)
        glibc = hasattr(libc, "gnu_get_libc_version")
    except (AttributeError, OSError, TypeError):
        return False
    if not glibc:
        return False
    mallopt.restype, mallopt.argtypes = ctypes.c_int, [ctypes.c_int, ctypes.c_int]
    ok = mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
    return mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1 and ok
