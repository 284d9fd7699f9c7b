"""Write files atomically: a product is either complete or absent, never half-written."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from .errors import bad_input

__all__ = ["atomic_path", "ensure_writable_dir"]


def ensure_writable_dir(path: str | os.PathLike) -> Path:
    """Create ``path`` if needed and check that files can be written in it."""
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise bad_input("--out", str(out), "a folder that can be created", str(exc)) from exc
    if not os.access(out, os.W_OK):
        raise bad_input("--out", str(out), "a writable folder", "choose another --out")
    return out


@contextlib.contextmanager
def atomic_path(final: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``final``; rename it to ``final`` only on success.

    On any exception (or Ctrl-C) the temporary file is removed and ``final`` is untouched.
    """
    final = Path(final)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{final.stem}.", suffix=final.suffix + ".tmp", dir=final.parent
    )
    os.close(fd)
    tmp_path = Path(tmp)
    umask = os.umask(0)
    os.umask(umask)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp makes 0600; products are ordinary files
        os.replace(tmp_path, final)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
