"""A Ctrl-C that third-party code cannot lose.

Python turns SIGINT into ``KeyboardInterrupt`` wherever the main thread happens to be, and
some libraries catch it there:

* pynmea2 converts a sentence's fields inside a bare ``except:`` (fixed at the source: the
  NMEA reader converts the fields itself, :mod:`factorgraph.field.nmea`);
* a pybind11 module (GTSAM) interrupted while it initialises raises
  ``ImportError: initialization failed`` instead;
* gpxpy reads each ``<time>`` inside a bare ``except:`` that returns ``None`` (the point is
  then counted as having no time).

Either way the user's Ctrl-C was lost: ``glacimap run`` ran on and wrote its products, or
stopped with a traceback. The handler installed by :func:`catching_ctrl_c` remembers that
the interrupt came, :func:`raise_if_interrupted` raises it again at the commands' progress
callbacks (between steps, where the library's ``with`` blocks roll back cleanly), and
``main`` reports any ending after a Ctrl-C as one (:class:`CtrlC`).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

__all__ = ["CtrlC", "catching_ctrl_c", "interrupted", "raise_if_interrupted"]

#: Set by the first SIGINT inside :func:`catching_ctrl_c`; cleared on its entry and exit.
_PENDING = threading.Event()


@dataclass
class CtrlC:
    """Whether a Ctrl-C came inside a :func:`catching_ctrl_c` block (set when it ends)."""

    came: bool = False


def _on_sigint(signum: int, frame) -> None:
    _PENDING.set()
    raise KeyboardInterrupt


@contextmanager
def catching_ctrl_c() -> Iterator[CtrlC]:
    """Install the remembering SIGINT handler for the block (main thread only), then restore
    the previous one. A SIGINT the shell set to be ignored (a background job) stays ignored.
    The remembered interrupt ends with the block (it never reaches a later command run in
    the same process, e.g. by a test), and the yielded :class:`CtrlC` says whether one came.
    """
    _PENDING.clear()
    seen = CtrlC()
    main = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGINT) if main else None
    install = main and previous is signal.default_int_handler
    if install:
        signal.signal(signal.SIGINT, _on_sigint)
    try:
        yield seen
    finally:
        if install:
            signal.signal(signal.SIGINT, previous)
        seen.came = _PENDING.is_set()
        _PENDING.clear()


def interrupted() -> bool:
    """Whether a Ctrl-C came in the :func:`catching_ctrl_c` block running now."""
    return _PENDING.is_set()


def raise_if_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` again when a Ctrl-C came and was swallowed on its way."""
    if _PENDING.is_set():
        raise KeyboardInterrupt
