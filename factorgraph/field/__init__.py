"""Field formats: a rover's own files (NMEA / GPX / RTKLIB GPS, odometry and tilt CSV,
OpenCV camera calibration, feature tracks, ``survey.json``) to and from a
:class:`~factorgraph.log.MeasurementLog`. The layout is documented in docs/field-format.md.
"""

from .fixes import UERE_M, GPSFixes
from .gate import gross_outliers
from .nmea import MAX_BAD_CHECKSUM_FRACTION
from .reader import FIELD_FORMAT, read_field_log
from .report import IngestReport
from .writer import write_field_log

__all__ = [
    "FIELD_FORMAT",
    "MAX_BAD_CHECKSUM_FRACTION",
    "UERE_M",
    "GPSFixes",
    "IngestReport",
    "gross_outliers",
    "read_field_log",
    "write_field_log",
]
