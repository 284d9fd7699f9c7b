"""Dense survey points thinned to block means before the fit (``reconstruct --block-size``).

A lidar strip or a drone's photogrammetric cloud gives millions of points; the GP maps
50,000 samples in seconds (``benchmarks/map_speed.py``). ``auto`` (the default) leaves a
survey of up to :data:`AUTO_REDUCE_ABOVE` samples as it is and reduces a larger one to
block means (:func:`terrain.block_samples.block_reduce`) on the smallest block that leaves
at most :data:`AUTO_MAX_SAMPLES`; a size in metres reduces on that block; ``none`` keeps
every point. Samples that carry the rover's along-track errors (``track_z_std_m``,
``shared_offset_std_m``, ``t_s``: what ``glacimap localize`` writes) are never averaged
into blocks: their errors are correlated along the track, which a block mean would mix.
"""

from __future__ import annotations

import math

import numpy as np

from terrain import ElevationSamples
from terrain.block_samples import BlockReduction, auto_block_size, block_reduce
from terrain.errors import bad_input

from .samples_io import SampleTable

__all__ = [
    "AUTO_MAX_SAMPLES",
    "AUTO_REDUCE_ABOVE",
    "block_size_option",
    "reduce_table",
    "reduction_note",
]

#: ``auto`` reduces a survey of more samples than this.
AUTO_REDUCE_ABOVE = 100_000
#: ... to at most this many block means.
AUTO_MAX_SAMPLES = 50_000


def block_size_option(text: str | float | None) -> float | str | None:
    """``--block-size``: ``"auto"``, ``None`` for ``"none"`` / ``0``, else a size in metres.

    Raises
    ------
    InputError
        Anything else (a negative, NaN or non-numeric size).
    """
    if text is None or str(text).strip().lower() in ("none", "0"):
        return None
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        size = float(text)
    except ValueError:
        size = math.nan
    if not (math.isfinite(size) and size > 0):
        raise bad_input(
            "--block-size",
            text,
            "auto, none, or a block edge in metres (> 0)",
            "e.g. --block-size 2 (one sample per 2 m block), or none to keep every point",
        )
    return size


def _along_track(table: SampleTable) -> bool:
    return bool(
        np.any(np.asarray(table.track_z_std) > 0)
        or table.shared_z_std > 0
        or "t_s" in table.samples.extra
    )


def reduction_note(red: BlockReduction, auto: bool) -> str:
    """How many points became how many samples, and why this block size when ``auto``."""
    if not auto:
        return red.note()
    return red.note() + (
        f" (auto: a survey of more than {AUTO_REDUCE_ABOVE:,} samples is reduced to at most "
        f"{AUTO_MAX_SAMPLES:,}; --block-size M to choose the block, none to keep every point)"
    )


def reduce_table(
    table: SampleTable, block_size: float | str | None
) -> tuple[SampleTable, BlockReduction | None]:
    """``table`` reduced to block means as ``block_size`` says (module docstring); its note
    gains a sentence saying how many points became how many samples.

    Raises
    ------
    InputError
        A size given for samples that carry along-track errors.
    """
    size = block_size_option(block_size) if isinstance(block_size, str) else block_size
    n = table.samples.n
    if size is None or (size == "auto" and n <= AUTO_REDUCE_ABOVE):
        return table, None
    if _along_track(table):
        if size != "auto":
            raise bad_input(
                "--block-size",
                block_size,
                "samples without along-track errors (track_z_std_m, shared_offset_std_m, t_s "
                "columns): a rover's errors are correlated along its track, block means mix them",
                "drop --block-size (these samples are mapped as they are)",
            )
        words = (
            f"{n:,} samples mapped as they are, not reduced to blocks: they carry along-track "
            "errors that block means would mix (the fit is slower)"
        )
        table.note = f"{table.note}; {words}" if table.note else words
        return table, None
    s = table.samples
    chosen = auto_block_size(s.xy, AUTO_MAX_SAMPLES) if size == "auto" else float(size)
    red = block_reduce(s.xy, s.z, chosen, z_var=s.z_var)
    samples = ElevationSamples(red.xy, red.z, red.z_var, crs=s.crs)
    note = reduction_note(red, size == "auto")
    note = f"{table.note}; {note}" if table.note else note
    return SampleTable(samples, np.zeros(samples.n), 0.0, note), red
