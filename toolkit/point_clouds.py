"""LAS / LAZ point clouds as samples, read in chunks (``glacimap reconstruct CLOUD.laz``).

A glacier's lidar campaign or a drone survey is tens to hundreds of millions of points in
several tiles: more than memory holds as samples. The clouds (one survey, any number of
files) are read three times, a chunk of :data:`CHUNK_POINTS` at a time (laspy + lazrs):

1. **Scan**: each file's CRS (the header's WKT or GeoTIFF keys: one for all files; ``--crs``
   must agree, or name one when the headers have none — never guessed; a CRS in feet is
   refused with the command that converts it), its points by ASPRS class, its withheld points,
   and the kept points' bounds in the map's CRS. Kept: ``classes`` when given, else ground
   (class 2) when any file classifies ground, else every point but noise (7, 18). Every point
   left out is counted by class.
2. **Occupancy** (``block_size="auto"`` and more than :data:`toolkit.sample_blocks.
   AUTO_REDUCE_ABOVE` kept points): the blocks each candidate size fills
   (:class:`terrain.block_samples.BlockOccupancy`), the smallest leaving at most
   :data:`toolkit.sample_blocks.AUTO_MAX_SAMPLES`.
3. **Sums**: each block's moments (:class:`terrain.block_samples.BlockAccumulator`), reduced
   to its quadratic at the points' centroid. Memory grows with the blocks, not the points.

Without reduction (``block_size=None``, or ``auto`` on a small cloud) the kept points are
the samples, points at one x, y averaged (counted).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS, Transformer

from terrain import ElevationSamples
from terrain.block_samples import BlockAccumulator, BlockOccupancy, BlockReduction
from terrain.errors import bad_input
from terrain.grid import check_same_crs

from .point_files import check_metres
from .samples_io import SampleTable, utm_zone_for

__all__ = ["CHUNK_POINTS", "CloudScan", "cloud_table", "scan_clouds", "stated_heights"]

#: Points read at a time (~40 bytes each in a chunk, ~300 while its sums are formed).
CHUNK_POINTS = 1_000_000
#: ASPRS LAS 1.4 classes (R15, table 17) the reader acts on.
GROUND, LOW_NOISE, HIGH_NOISE = 2, 7, 18
_CLASS_NAMES = {1: "unclassified", 3: "low vegetation", 4: "medium vegetation",
                5: "high vegetation", 6: "building", 7: "low noise", 9: "water",
                18: "high noise"}  # fmt: skip


def _class_words(counts: np.ndarray) -> str:
    return ", ".join(
        f"{int(c):,} class {v}" + (f" ({_CLASS_NAMES[v]})" if v in _CLASS_NAMES else "")
        for v, c in enumerate(counts)
        if c
    )


@dataclass
class CloudScan:
    """What pass 1 found in the clouds (:func:`scan_clouds`)."""

    paths: list[Path]
    keep: np.ndarray  # (256,) bool: the classes kept
    counts: np.ndarray  # (256,) points by class, withheld ones apart
    withheld: int
    crs: CRS  # the map's (projected, metres)
    transformer: Transformer | None  # header CRS -> map CRS, when they differ
    bounds: tuple[float, float, float, float]  # the kept points', map CRS, m
    notes: list[str] = field(default_factory=list)

    @property
    def n_kept(self) -> int:
        """Points kept for the map."""
        return int(self.counts[self.keep].sum())

    def chunks(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """The kept points, ``(xy (n, 2) m in the map's CRS, z (n,) m)`` a chunk at a time."""
        for _, xy, z in _read(self.paths, self.keep, self.transformer):
            yield xy, z


def _open(path: Path, field_name: str) -> Any:
    import laspy

    try:
        return laspy.open(path)
    except Exception as exc:  # laspy's LaspyException, lazrs' errors, OSError
        raise bad_input(field_name, path.name, "a LAS / LAZ file laspy reads", str(exc)) from exc


def _read(
    paths: list[Path], keep: np.ndarray | None, transformer: Transformer | None
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``(codes, xy, z)`` chunks of every file: all points (``keep`` None, withheld ones
    with code -1) or the kept ones only, projected by ``transformer``."""
    for path in paths:
        with _open(path, "SAMPLES") as reader:
            chunks = reader.chunk_iterator(CHUNK_POINTS)
            while True:
                try:  # a file cut short or corrupt fails here, a chunk in
                    pts = next(chunks)
                except StopIteration:
                    break
                except Exception as exc:  # lazrs' LazrsError, laspy's LaspyException
                    raise bad_input(
                        "SAMPLES", path.name, "a LAS / LAZ file laspy reads to its end", str(exc)
                    ) from exc
                code = np.asarray(pts.classification, dtype=np.int64)
                code = np.where(np.asarray(pts.withheld, dtype=bool), -1, code)
                mask = slice(None) if keep is None else np.flatnonzero((code >= 0) & keep[code])
                x, y = np.asarray(pts.x)[mask], np.asarray(pts.y)[mask]
                if transformer is not None:
                    x, y = transformer.transform(x, y)
                yield code[mask], np.column_stack([x, y]), np.asarray(pts.z, float)[mask]


def _header_crs(paths: list[Path], field_name: str) -> CRS | None:
    """The one CRS the files' headers name (None when none does)."""
    found: dict[str, CRS] = {}
    for path in paths:
        with _open(path, field_name) as reader:
            try:
                crs = reader.header.parse_crs()
            except Exception as exc:  # pyproj's CRSError on a broken VLR
                raise bad_input(field_name, path.name, "a readable CRS", str(exc)) from exc
        if crs is not None:
            check_metres(crs, field_name, path.name)
            found[path.name] = crs.sub_crs_list[0] if crs.is_compound else crs
    crss = list(found.values())
    for name, crs in found.items():
        if not crs.equals(crss[0], ignore_axis_order=True):
            raise bad_input(
                field_name,
                f"{name}: {crs.to_string()}, {next(iter(found))}: {crss[0].to_string()}",
                "clouds of one survey in one CRS",
                "reproject one (pdal translate ... reprojection) or map them apart",
            )
    return crss[0] if crss else None


def stated_heights(paths: list[str | Path]) -> tuple[str | None, str]:
    """The height datum the clouds' header CRS (or a raster's CRS) states: ``(datum, "")``
    for the ellipsoid, a world geoid or a national datum
    (:func:`terrain.vertical_datum.split_vertical`), ``(None, words)`` for a vertical CRS
    glacimap cannot carry (named, not converted: ``change`` and ``certify`` take it as not
    stated), ``(None, "")`` when no file says."""
    from terrain.errors import InputError
    from terrain.vertical_datum import split_vertical

    from .point_files import point_format

    for path in map(Path, paths):
        if point_format(path) == "raster":  # a DSM as samples: its GeoTIFF's CRS
            import rasterio

            with rasterio.open(path) as ds:
                crs = None if ds.crs is None else CRS.from_wkt(ds.crs.to_wkt())
        else:
            with _open(path, "SAMPLES") as reader:
                crs = reader.header.parse_crs()
        if crs is None or not crs.is_compound:
            continue
        try:
            return split_vertical(crs)[1], ""
        except InputError:
            vertical = crs.sub_crs_list[-1]
            return None, (
                f"{vertical.name} heights, as {path.name}'s CRS states ({vertical.to_string()}); "
                "glacimap does not convert this datum: change / certify take it as not stated"
            )
    return None, ""


def scan_clouds(
    paths: list[str | Path], crs: Any = None, classes: tuple[int, ...] | None = None
) -> CloudScan:
    """Pass 1 over the clouds (module docstring).

    Raises
    ------
    InputError
        A file laspy cannot read; headers in different CRSs, or none and no ``crs``; a CRS in
        feet; no point of the classes kept.
    CRSMismatchError
        ``crs`` and the headers' CRS differ.
    """
    from .certify_io import any_crs

    paths = [Path(p) for p in paths]
    header = _header_crs(paths, "SAMPLES")
    given = None if crs is None else any_crs(crs, "--crs")
    if header is not None:
        check_same_crs(given, header, "--crs", f"{paths[0].name} (LAS header)")
    use = header if header is not None else given
    if use is None:
        raise bad_input(
            "--crs",
            None,
            f"the CRS of {', '.join(p.name for p in paths)}'s points (the header names none)",
            "pass --crs EPSG:326zz (the cloud's CRS); glacimap never guesses it",
        )
    counts, withheld = np.zeros(256, np.int64), 0
    lo, hi = np.full((256, 2), np.inf), np.full((256, 2), -np.inf)  # bounds by class
    for code, xy, _ in _read(paths, None, None):
        withheld += int((code < 0).sum())
        ok = code >= 0
        counts += np.bincount(code[ok], minlength=256)
        for c in np.unique(code[ok]):
            pick = xy[code == c]
            lo[c], hi[c] = np.minimum(lo[c], pick.min(axis=0)), np.maximum(hi[c], pick.max(0))
    if classes is not None:
        keep, rule = np.isin(np.arange(256), classes), f"classes {', '.join(map(str, classes))}"
    elif counts[GROUND]:
        keep, rule = np.arange(256) == GROUND, "ground points (class 2)"
    else:
        keep = ~np.isin(np.arange(256), (LOW_NOISE, HIGH_NOISE))
        rule = "not classified: all but noise (classes 7, 18)"
    names = ", ".join(p.name for p in paths)
    total = int(counts.sum()) + withheld
    notes = [f"{names}: {total:,} points, {rule} kept"]
    if (counts * ~keep).any():
        notes.append(f"left out {_class_words(counts * ~keep)}")
    if withheld:
        notes.append(f"left out {withheld:,} withheld points")
    if not (counts * keep).any():
        raise bad_input(
            "SAMPLES",
            f"{names} ({_class_words(counts)})",
            "some points of the classes kept",
            "choose the classes with --point-classes (e.g. 1,2)",
        )
    w, s = lo[keep].min(axis=0)
    e, n = hi[keep].max(axis=0)
    transformer, map_crs = None, use
    if use.is_geographic:  # degrees: to the UTM zone of the kept points' centre
        fix = "reproject the cloud to a polar stereographic CRS (EPSG:3031 / 3413)"
        map_crs = utm_zone_for((w + e) / 2, (s + n) / 2, fix)
        transformer = Transformer.from_crs(use, map_crs, always_xy=True)
        xs, ys = transformer.transform([w, w, e, e], [s, n, s, n])
        pad = 0.001 * max(np.ptp(xs), np.ptp(ys))  # a graticule box's edges bow in UTM
        w, s, e, n = min(xs) - pad, min(ys) - pad, max(xs) + pad, max(ys) + pad
        notes.append(f"projected to {map_crs.to_string()} ({map_crs.name})")
    notes.append("a cloud states no per-point noise")
    return CloudScan(paths, keep, counts, withheld, map_crs, transformer, (w, s, e, n), notes)


def cloud_table(
    paths: list[str | Path],
    crs: Any = None,
    classes: tuple[int, ...] | None = None,
    block_size: float | str | None = "auto",
) -> tuple[SampleTable, BlockReduction | None]:
    """The clouds' kept points as samples: block samples when ``block_size`` says so
    (:func:`toolkit.sample_blocks.reduce_table`'s rule), else every point.

    Returns
    -------
    (SampleTable, BlockReduction or None)
        The samples in the map's CRS with a note of everything counted, and the reduction.
    """
    from .sample_blocks import (
        AUTO_MAX_SAMPLES,
        AUTO_REDUCE_ABOVE,
        block_size_option,
        reduction_note,
    )

    size = block_size_option(block_size) if isinstance(block_size, str) else block_size
    scan = scan_clouds(paths, crs, classes)
    notes = list(scan.notes)
    if size is None or (size == "auto" and scan.n_kept <= AUTO_REDUCE_ABOVE):
        parts = list(scan.chunks())
        xy, z = np.vstack([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
        samples = ElevationSamples(xy, z, 0.0, crs=scan.crs.to_string(), duplicates="average")
        if samples.n_merged:
            notes.append(f"{samples.n_merged:,} points at the x, y of another averaged")
        return SampleTable(samples, np.zeros(samples.n), 0.0, "; ".join(notes)), None
    if size == "auto":
        occupancy = BlockOccupancy(scan.bounds, AUTO_MAX_SAMPLES)
        for xy, _ in scan.chunks():
            occupancy.add(xy)
        chosen = occupancy.size()
    else:
        chosen = float(size)
    w, s = scan.bounds[:2]
    acc = BlockAccumulator(chosen, (np.floor(w / chosen) * chosen, np.floor(s / chosen) * chosen))
    for xy, z in scan.chunks():
        acc.add(xy, z)
    red = acc.result()
    notes.append(reduction_note(red, size == "auto"))
    samples = ElevationSamples(red.xy, red.z, red.z_var, crs=scan.crs.to_string())
    return SampleTable(samples, np.zeros(samples.n), 0.0, "; ".join(notes)), red
