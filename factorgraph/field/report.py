"""What the field reader did with a folder: sources, clock, and everything it skipped."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

__all__ = ["IngestReport"]


@dataclass
class IngestReport:
    """Counts and choices of one :func:`factorgraph.read_field_log` call (plain JSON values).

    Attributes
    ----------
    gps_file, gps_format : str
        The GPS file read and its format (``nmea``, ``gpx``, ``rtklib``).
    gps_records : int
        Position records in the GPS file (used or not).
    gps_used : int
        Fixes that became keyframe GPS factors.
    gps_skipped : dict
        GPS records not used, by reason (``bad_checksum``, ``no_solution``, ``nan_fix``,
        ``duplicate_time``, ``backwards_time``, ``gross_outlier``, ``between_keyframes``,
        ``outside_traverse``, ``extra_fix_same_keyframe``, ...).
    gps_quality : dict
        Used fixes by solution kind (``single``, ``dgps``, ``rtk_fixed``, ...).
    gps_sigma_median_m : list of float
        Median per-fix 1-sigma (E, N, U) of the used fixes (m).
    gps_gaps : dict
        ``count`` of intervals between used fixes longer than ``threshold_s`` (3x the median
        interval, at least 2 s), the ``longest_s`` and their ``total_s``.
    clock_offset_s : float
        ``utc_s - t_rover_s`` applied; ``clock_source`` is ``argument``, ``survey.json`` or
        ``estimated`` (then ``clock_fit`` holds the course-alignment ``resultant`` and
        ``contrast``, :mod:`factorgraph.field.clock`).
    sync_tolerance_s : float
        Largest gap between a fix and its keyframe.
    tilt : str
        ``used``, ``absent`` or ``not used: <reason>``.
    tracks : str
        Where the feature observations came from: ``tracks.csv``, or the camera front-end
        on the folder's frames (``images/``).
    tracks_skipped : dict
        Feature observations not used, by reason.
    front_end : dict
        What the front-end did on ``images/`` (:func:`factorgraph.vision.track_log_frames`:
        ``source``, ``tracks``, ``views_per_keyframe``, ``frames_skipped``, ``rejected``);
        ``{}`` when the observations are ``tracks.csv``'s.
    camera : str
        Where the intrinsics came from, and whether tracks were undistorted.
    lever_arm_m : list of float
        Antenna position in the body frame (m) that was removed from the fixes.
    stops : dict
        ``stops.csv`` (stops on ground-control points): ``file``, ``rows``, stop
        ``keyframes``, the ``points`` stood on and the rows ``skipped`` by reason; ``{}``
        without the file.
    warnings : list of str
        What was read but looks wrong (a map CRS whose area of use misses the survey).
    """

    gps_file: str = ""
    gps_format: str = ""
    gps_records: int = 0
    gps_used: int = 0
    gps_skipped: dict[str, int] = field(default_factory=dict)
    gps_quality: dict[str, int] = field(default_factory=dict)
    gps_sigma_median_m: list[float] = field(default_factory=list)
    gps_gaps: dict[str, float] = field(default_factory=dict)
    clock_offset_s: float = 0.0
    clock_source: str = ""
    clock_fit: dict[str, float] = field(default_factory=dict)
    sync_tolerance_s: float = 0.0
    tilt: str = "absent"
    tracks: str = ""
    tracks_skipped: dict[str, int] = field(default_factory=dict)
    front_end: dict[str, Any] = field(default_factory=dict)
    camera: str = ""
    lever_arm_m: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    stops: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    @property
    def n_skipped(self) -> int:
        """GPS records not used, all reasons."""
        return int(sum(self.gps_skipped.values()))

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON (recorded in the log's ``ingest`` and its ``meta.json``)."""
        return asdict(self)

    def lines(self) -> list[str]:
        """Human-readable summary, one fact per line."""
        out = [
            f"GPS {self.gps_file} ({self.gps_format}): {self.gps_used} of {self.gps_records} "
            f"records used",
            f"clock offset {self.clock_offset_s:.3f} s ({self.clock_source}"
            + (
                f", +- {self.clock_fit['standard_error_s']:.3f} s)"
                if "standard_error_s" in self.clock_fit
                else ")"
            ),
        ]
        out += _skipped("GPS records", self.gps_skipped)
        if self.gps_gaps.get("count"):
            g = self.gps_gaps
            out.append(f"  {g['count']:.0f} GPS gaps, longest {g['longest_s']:.1f} s")
        out += _skipped("observations", self.tracks_skipped)
        out += _front_end_lines(self.front_end)
        out.append(f"tilt {self.tilt}; camera {self.camera}")
        if self.stops:
            st = self.stops
            out.append(
                f"stops {st['file']}: {st['keyframes']} keyframes on {len(st['points'])} "
                f"control points ({', '.join(st['points'][:8])})"
            )
            out += _skipped("stop rows", st["skipped"])
        out += [f"warning: {w}" for w in self.warnings]
        return out


def _skipped(what: str, counts: dict[str, int]) -> list[str]:
    """One line per reason: ``  skipped N <what>: <reason>``."""
    return [f"  skipped {n} {what}: {r}" for r, n in sorted(counts.items())]


def _front_end_lines(fe: dict[str, Any]) -> list[str]:
    """What the camera front-end did on the folder's frames (none without frames)."""
    if not fe:
        return []
    head = (
        f"tracks from the front-end on {fe['folder']} ({fe['source']}): "
        f"{fe['tracks']} tracks, {fe['views_per_keyframe']:.1f} views per keyframe"
    )
    rejected = ", ".join(f"{r} {n}" for r, n in fe["rejected"].items() if n) or "none"
    return [head, *_skipped("frames", fe["frames_skipped"]), f"  front-end rejections: {rejected}"]
