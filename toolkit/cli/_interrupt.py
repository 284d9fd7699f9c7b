"""A Ctrl-C that third-party code cannot lose.

Python turns SIGINT into ``KeyboardInterrupt`` wherever the main thread happens to be, and
some libraries catch it there:

* pynmea2 converts a sentence's fields inside a bare ``except:`` (fixed at the source: the
  NMEA reader converts the fields itself, :mod:`factorgraph.field.nmea`);
* a pybind11 module (GTSAM) interrupted while it initialises raises
  ``ImportError: initialization failed`` instead.

Either way the user's Ctrl-C was lost: ``glacimap run`` ran on and wrote its products, or
stopped with a traceback. The handler installed by :func:`catching_ctrl_c` remembers that
the interrupt came, :func:`raise_if_interrupted` raises it again at the commands' progress
callbacks (between steps, where the library's ``with`` blocks roll back cleanly), and
:func:`interrupted` lets ``main`` report any ending after a Ctrl-C as one.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["catching_ctrl_c", "interrupted", "raise_if_interrupted"]

#: Set by the first SIGINT; cleared when :func:`catching_ctrl_c` is entered.
_PENDING = threading.Event()


def _on_sigint(signum: int, frame) -> None:
    _PENDING.set()
    raise KeyboardInterrupt


@contextmanager
def catching_ctrl_c() -> Iterator[None]:
    """Install the remembering SIGINT handler for the block (main thread only), then restore
    the previous one. A SIGINT the shell set to be ignored (a background job) stays ignored."""
    _PENDING.clear()
    main = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGINT) if main else None
    install = main and previous is signal.default_int_handler
    if install:
        signal.signal(signal.SIGINT, _on_sigint)
    try:
        yield
    finally:
        if install:
            signal.signal(signal.SIGINT, previous)


def interrupted() -> bool:
    """Whether a Ctrl-C came since :func:`catching_ctrl_c` was entered."""
    return _PENDING.is_set()


def raise_if_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` again when a Ctrl-C came and was swallowed on its way."""
    if _PENDING.is_set():
        raise KeyboardInterrupt
