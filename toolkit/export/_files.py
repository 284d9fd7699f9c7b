"""Output paths of the exports: checked up front, written atomically under their own extension."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

from terrain.atomic import atomic_path
from terrain.errors import bad_input

__all__ = [
    "atomic_file",
    "check_target",
    "output_folder",
    "previous_products",
    "remove_stale",
    "staged_folder",
]


def check_target(path: str | os.PathLike, suffixes: tuple[str, ...], field: str) -> Path:
    """Validate an output file path before any work is done.

    Parameters
    ----------
    path : path-like
        The file to write.
    suffixes : tuple of str
        Accepted extensions, lower case with the dot (``(".tif", ".tiff")``); GIS clients and
        GDAL's validators pick the format from it.
    field : str
        Name of the argument, for the error message.

    Returns
    -------
    pathlib.Path
        ``path`` as a Path.

    Raises
    ------
    terrain.errors.InputError
        Wrong extension, a missing or non-directory parent folder, or a folder that cannot be
        written.
    """
    try:
        out = Path(path)
    except TypeError as exc:
        raise bad_input(field, path, "a file path", "pass a str or pathlib.Path") from exc
    if out.suffix.lower() not in suffixes:
        raise bad_input(
            field, str(out), f"a file name ending in {' or '.join(suffixes)}", "rename it"
        )
    parent = out.parent
    if not parent.is_dir():
        raise bad_input(
            field, str(out), "a path inside an existing folder", f"create {parent} first"
        )
    if not os.access(parent, os.W_OK | os.X_OK):
        raise bad_input(field, str(out), "a path in a writable folder", "choose another folder")
    if out.is_dir():
        raise bad_input(field, str(out), "a file path, not a folder", "add a file name")
    return out


@contextlib.contextmanager
def atomic_file(final: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``final`` that keeps ``final``'s extension.

    :func:`terrain.atomic.atomic_path` names its temporary ``.<stem>.<random><suffix>.tmp``;
    GDAL drivers (GeoPackage warns about the extension), VTK and image writers look at the
    extension, so this yields that name without ``.tmp`` and moves the finished file onto it.
    On any error both temporaries are removed and ``final`` is untouched (docs/architecture.md §4).
    """
    with atomic_path(final) as tmp:
        inner = tmp.with_name(tmp.name[: -len(".tmp")])
        try:
            yield inner
            os.replace(inner, tmp)
        except BaseException:
            inner.unlink(missing_ok=True)
            for sidecar in ("-journal", "-wal", "-shm", ".aux.xml"):  # SQLite / GDAL leftovers
                Path(str(inner) + sidecar).unlink(missing_ok=True)
            raise


@contextlib.contextmanager
def staged_folder(out: Path) -> Iterator[Path]:
    """Yield a hidden staging folder inside ``out``; on success move every file written there
    into ``out``, on any error delete it, so a set of products appears together or not at all.

    Each product inside the staging folder is still written atomically; the final moves are
    renames within one file system. Files of the same name in ``out`` are replaced.
    """
    import shutil
    import tempfile

    out = Path(out)
    stage = Path(tempfile.mkdtemp(prefix=".staging.", dir=out))
    try:
        yield stage
        names = sorted(p.name for p in stage.iterdir())
        clash = [n for n in names if (out / n).is_dir()]
        if clash:
            raise bad_input(
                "--out", str(out / clash[0]), "no folder named like a product", "remove it"
            )
        for name in names:
            os.replace(stage / name, out / name)
        stage.rmdir()
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise


@contextlib.contextmanager
def output_folder(out: str | os.PathLike) -> Iterator[Path]:
    """Create ``out`` (and missing parents) and check it is writable; if the block fails and
    the folders this created hold no file, remove them again: a failed command leaves
    nothing behind, not even an empty ``--out``."""
    import shutil

    from terrain.atomic import ensure_writable_dir

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise bad_input("--out", str(out), "a folder, not a file", "choose another --out")
    first_new = None
    for folder in (out, *out.parents):
        if folder.exists():
            break
        first_new = folder
    folder = ensure_writable_dir(out)
    try:
        yield folder
    except BaseException:
        if first_new is not None and not any(p.is_file() for p in first_new.rglob("*")):
            shutil.rmtree(first_new, ignore_errors=True)
        raise


def previous_products(out: Path, summary: str = "summary.json") -> list[str]:
    """The product files an earlier run listed in ``out/summary.json`` (``products``)."""
    import json

    try:
        listed = json.loads((Path(out) / summary).read_text()).get("products", [])
    except (OSError, ValueError, AttributeError):
        return []
    return [str(n) for n in listed if isinstance(n, str) and "/" not in n and n != ".."]


def remove_stale(out: Path, before: list[str], now: list[str]) -> list[str]:
    """Delete the files of ``before`` (an earlier run's products in ``out``) that this run did
    not write (``now``): a second run into the same ``--out`` must not leave, say, the first
    run's ``report.html`` beside a certificate it does not describe. Returns their names."""
    gone = []
    for name in sorted(set(before) - set(now)):
        path = Path(out) / name
        if path.is_file():
            path.unlink()
            gone.append(name)
    return gone
