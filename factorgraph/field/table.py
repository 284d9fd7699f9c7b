"""Point tables as survey software and spreadsheets write them (control, checkpoints, samples).

One reader for every small CSV a user brings (:func:`factorgraph.read_control`,
``toolkit.certify_io.read_checkpoints``, ``toolkit.samples_io.read_samples``), so that they
accept the same files:

* delimiter ``,``, ``;``, tab or ``|``, chosen from the header line (the one that splits it
  into the most cells); with ``;``, tab or ``|`` a decimal comma (``6475304,53``, the European
  spreadsheet export) is read as a decimal point;
* UTF-8 with or without a byte-order mark; a file that is not UTF-8 is read as Windows-1252
  (Excel's "CSV" on Windows) and the table says so;
* quoted cells, CRLF line ends, blank lines and ``#`` comment lines;
* header names compared by :func:`header_key`: case, surrounding spaces and a unit suffix
  (``Easting (m)``, ``z [m]``, ``height_m``) do not matter.

A coordinate system can also sit beside the file: ``<stem>.crs`` (``EPSG:32608``) or
``<stem>.prj`` (WKT), :func:`sidecar_crs`.
"""

from __future__ import annotations

import csv
import io
import re
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path

from terrain.errors import bad_input

__all__ = [
    "DELIMITERS",
    "TextTable",
    "csv_dialect",
    "header_key",
    "read_text_table",
    "sidecar_crs",
]

#: Delimiters a table may use; the header line decides (ties: the earlier one).
DELIMITERS = (",", ";", "\t", "|")
_DECIMAL_COMMA = re.compile(r"^\s*[+-]?\d*,\d+([eE][+-]?\d+)?\s*$")


@dataclass
class TextTable:
    """A text table as read.

    Attributes
    ----------
    header : list of str
        Column names, stripped.
    rows : list of list of str
        Data rows (blank and ``#`` lines removed), cells as text with a decimal comma turned
        into a point where the delimiter is not a comma.
    delimiter : str
        The delimiter found.
    encoding : str
        ``utf-8`` or ``cp1252``.
    notes : list of str
        What was read differently from a plain comma-separated UTF-8 file (for reports).
    """

    header: list[str]
    rows: list[list[str]]
    delimiter: str = ","
    encoding: str = "utf-8"
    notes: list[str] = field(default_factory=list)

    def columns(self) -> dict[str, list[str]]:
        """``{header: cells}``, the rows checked to have as many cells as the header."""
        return {h: [r[j] for r in self.rows] for j, h in enumerate(self.header)}


def header_key(name: str, known: Collection[str] = ()) -> str:
    """A header name as compared with the aliases ``known``: lower case, spaces and dashes as
    ``_``, a trailing unit in brackets (``(m)``, ``[deg]``) dropped, and a ``_m`` suffix when
    what is left is in ``known``."""
    key = re.sub(r"\s*[\(\[][^\)\]]*[\)\]]\s*$", "", str(name).strip().lower())
    key = re.sub(r"[\s\-]+", "_", key)
    return key[:-2] if key.endswith("_m") and key[:-2] in known else key


def _decode(raw: bytes) -> tuple[str, str]:
    try:
        return raw.decode("utf-8-sig"), "utf-8"
    except UnicodeDecodeError:
        return raw.decode("cp1252", errors="replace"), "cp1252"


def _split(line: str, delimiter: str) -> list[str]:
    return next(csv.reader([line], delimiter=delimiter), [])


def _delimiter(header_line: str) -> str:
    counts = [len(_split(header_line, d)) for d in DELIMITERS]
    return DELIMITERS[counts.index(max(counts))]


def csv_dialect(path: str | Path) -> dict[str, str]:
    """``pandas.read_csv`` keywords for a table in any of the accepted dialects: ``sep``
    (from the header line), ``decimal`` (``","`` when the delimiter is not a comma and one of
    the first 49 data lines has a decimal comma) and ``encoding`` (``utf-8-sig`` or ``cp1252``).
    The field folder's rover tables (odometry, tilt, tracks, stops) are read with it."""
    text, encoding = _decode(Path(path).read_bytes()[:65536])
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    sep = _delimiter(lines[0]) if lines else ","
    comma = sep != "," and any(
        _DECIMAL_COMMA.match(c) for ln in lines[1:50] for c in _split(ln, sep)
    )
    return {
        "sep": sep,
        "decimal": "," if comma else ".",
        "encoding": "utf-8-sig" if encoding == "utf-8" else "cp1252",
        "comment": "#",
    }


def read_text_table(path: str | Path, what: str) -> TextTable:
    """Read a delimited text table with a header row (module docstring for what is accepted).

    Parameters
    ----------
    path : path
        The file.
    what : str
        The field name used in errors (``"control file"``, ``"CHECKPOINTS"``).

    Raises
    ------
    terrain.errors.InputError
        A missing or unreadable file, no header, or a row with another number of cells than
        the header (named by its line number).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise bad_input(what, str(path), "a readable file", str(exc)) from exc
    text, encoding = _decode(raw)
    notes = [] if encoding == "utf-8" else ["read as Windows-1252 (not UTF-8)"]
    lines = [
        (i + 1, ln)
        for i, ln in enumerate(io.StringIO(text, newline=None).read().splitlines())
        if ln.strip() and not ln.lstrip().startswith("#")
    ]
    if not lines:
        raise bad_input(what, path.name, "a header row and data rows", "the file is empty")
    delimiter = _delimiter(lines[0][1])
    if delimiter != ",":
        notes.append(f"delimiter {delimiter!r}")
    parsed = list(csv.reader((ln for _, ln in lines), delimiter=delimiter))
    header = [h.strip() for h in parsed[0]]
    rows = [[c.strip() for c in r] for r in parsed[1:] if any(c.strip() for c in r)]
    line_no = [
        n for (n, _), r in zip(lines[1:], parsed[1:], strict=True) if any(c.strip() for c in r)
    ]
    bad = [i for i, r in enumerate(rows) if len(r) != len(header)]
    if bad:
        i = bad[0]
        raise bad_input(
            f"{path.name} line {line_no[i]}",
            rows[i],
            f"{len(header)} cells like the header {header} (delimiter {delimiter!r})",
            f"fix the row ({len(bad)} rows differ); quote cells that contain the delimiter",
        )
    if delimiter != ",":
        n_comma = 0
        for r in rows:
            for j, c in enumerate(r):
                if _DECIMAL_COMMA.match(c):
                    r[j] = c.replace(",", ".")
                    n_comma += 1
        if n_comma:
            notes.append(f"decimal comma in {n_comma} cells")
    return TextTable(header, rows, delimiter, encoding, notes)


def sidecar_crs(path: str | Path) -> tuple[str, str] | None:
    """``(crs text, "sidecar NAME")`` from ``<stem>.crs`` (e.g. ``EPSG:32608``) or
    ``<stem>.prj`` (WKT) beside ``path``; None when neither exists."""
    path = Path(path)
    for suffix in (".crs", ".prj"):
        side = path.with_suffix(suffix)
        if side.is_file():
            return side.read_text(
                encoding="utf-8", errors="replace"
            ).strip(), f"sidecar {side.name}"
    return None
