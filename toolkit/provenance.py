"""Which input files made a product, and what keeps two runs' products byte-identical.

A product (certificate, GeoTIFF/netCDF/mesh/GeoPackage metadata) names its inputs by file
name and SHA-256, never by the absolute path it was read from: the same inputs and seed give
the same bytes whatever the output folder (docs/pipeline.md, "Reproducible products").
Wall-clock timings are not certified quantities: they go to ``summary.json`` only.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

__all__ = [
    "GPKG_LAST_CHANGE_DEFAULT",
    "TIMING_KEYS",
    "file_sha256",
    "gpkg_last_change",
    "input_record",
    "split_timings",
]

#: Keys of :func:`toolkit.stages.localization_summary` that are wall-clock seconds (they
#: differ run to run): kept out of the certificate, written to ``summary.json``.
TIMING_KEYS = ("step_median_s", "step_p95_s", "marginals_s")

#: ``gpkg_contents.last_change`` of every GeoPackage glacimap writes when
#: ``SOURCE_DATE_EPOCH`` is not set: a fixed stamp (the Unix epoch), so that the file's
#: bytes depend on its content only (GDAL stamps the wall clock otherwise).
GPKG_LAST_CHANGE_DEFAULT = "1970-01-01T00:00:00.000Z"

_CHUNK = 1 << 20


def file_sha256(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's bytes (read 1 MiB at a time)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def input_record(role: str, source: Any) -> dict[str, Any] | None:
    """Provenance of one input: ``{"role", "name", "sha256"}`` for a file; for a folder (a
    rover's field folder, a ``glacimap-log/1`` folder) also ``"n_files"`` and ``"files"``
    (each regular file below it, relative path -> SHA-256), and ``"sha256"`` over the lines
    ``"<relative path> <sha256>\\n"`` in sorted order. ``name`` is the base name, never the
    absolute path. ``None`` for ``None``; ``"sha256": None`` for an in-memory object.

    Parameters
    ----------
    role : str
        What the input is: ``"log"``, ``"prior"``, ``"samples"``, ``"control"``,
        ``"checkpoints"``.
    source : path-like, rasterio dataset, RasterMean, or in-memory object
        The input as the caller passed it. An object without a file (checkpoints or control
        read earlier) is named by its ``source`` and ``sha256`` attributes when it has them.
    """
    if source is None:
        return None
    path = _as_path(source)
    if path is None:  # Checkpoints / ControlPoints built in memory keep a name and a hash
        name = getattr(source, "source", None)
        sha = getattr(source, "sha256", None)
        return {
            "role": role,
            "name": str(name) if isinstance(name, str) else f"in memory ({type(source).__name__})",
            "sha256": sha if isinstance(sha, str) else None,
        }
    if path.is_dir():
        files = sorted(p for p in path.rglob("*") if p.is_file())
        table = {p.relative_to(path).as_posix(): file_sha256(p) for p in files}
        digest = hashlib.sha256(
            "".join(f"{rel} {sha}\n" for rel, sha in table.items()).encode()
        ).hexdigest()
        return {
            "role": role,
            "name": path.name,
            "sha256": digest,
            "n_files": len(table),
            "files": table,
        }
    return {"role": role, "name": path.name, "sha256": file_sha256(path)}


def _as_path(source: Any) -> Path | None:
    """A path-like, an open rasterio dataset's file or a RasterMean's file; else None."""
    if isinstance(source, str | os.PathLike):
        return Path(source) if Path(source).exists() else None
    for name in (
        getattr(source, "name", None),  # rasterio dataset
        getattr(getattr(source, "source", None), "path", None),  # terrain.RasterMean
    ):
        if isinstance(name, str) and name and Path(name).is_file():
            return Path(name)
    return None


def split_timings(summary: dict[str, Any]) -> tuple[dict[str, Any], dict[str, float]]:
    """``summary`` without its wall-clock entries (:data:`TIMING_KEYS` and
    ``view_gate.seconds``), and those entries (for ``summary.json``)."""
    kept = {k: v for k, v in summary.items() if k not in TIMING_KEYS}
    times = {k: summary[k] for k in TIMING_KEYS if k in summary}
    gate = summary.get("view_gate")
    if isinstance(gate, dict) and "seconds" in gate:
        kept["view_gate"] = {k: v for k, v in gate.items() if k != "seconds"}
        times["view_gate_s"] = gate["seconds"]
    return kept, times


def gpkg_last_change() -> str:
    """The ``last_change`` stamp for GeoPackages: ``SOURCE_DATE_EPOCH`` (the
    reproducible-builds convention, seconds since 1970 UTC) when set, else
    :data:`GPKG_LAST_CHANGE_DEFAULT`."""
    from datetime import UTC, datetime

    epoch = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    if not epoch:
        return GPKG_LAST_CHANGE_DEFAULT
    try:
        stamp = datetime.fromtimestamp(int(epoch), tz=UTC)
    except (ValueError, OverflowError, OSError) as exc:
        from terrain.errors import bad_input

        raise bad_input(
            "SOURCE_DATE_EPOCH",
            epoch,
            "whole seconds since 1970-01-01 UTC",
            "unset it, or set e.g. SOURCE_DATE_EPOCH=$(git log -1 --format=%ct)",
        ) from exc
    return stamp.strftime("%Y-%m-%dT%H:%M:%S.000Z")
