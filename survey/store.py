"""A crash-safe result store for Monte Carlo sweeps: one SQLite file, one row per task.

Each finished task is committed in its own transaction, keyed by its task key, so a sweep
killed half-way keeps every finished row, never a half-written one, and a re-run skips them.
The sweep's configuration is stored beside the rows; reopening with a different
configuration is refused (it would mix two experiments in one table).
"""

from __future__ import annotations

import json
import os
import sqlite3
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from terrain.errors import bad_input

__all__ = ["ResultStore"]

_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE results (
    task TEXT PRIMARY KEY,
    terrain INTEGER NOT NULL,
    pattern TEXT NOT NULL,
    n_swaths INTEGER NOT NULL,
    run INTEGER NOT NULL,
    payload TEXT NOT NULL
);
"""


class ResultStore:
    """SQLite store of sweep results at ``path``.

    Parameters
    ----------
    path : path-like
        The ``.sqlite`` file. Created atomically (schema written to a temporary file, then
        renamed) if it does not exist.
    config : dict
        JSON-serialisable sweep configuration; must equal the stored one when reopening.
    """

    def __init__(self, path: str | os.PathLike, config: dict[str, Any]) -> None:
        self.path = Path(path)
        text = json.dumps(config, sort_keys=True)
        if not self.path.exists():
            self._create(text)
        self._con = sqlite3.connect(self.path)
        stored = self._con.execute("SELECT value FROM meta WHERE key = 'config'").fetchone()
        if stored is None or stored[0] != text:
            self._con.close()
            raise bad_input(
                "--out",
                str(self.path.parent),
                "a result store made with the same sweep configuration",
                "choose a new output folder for a different sweep, or re-run with the "
                "original settings to resume",
            )
        row = self._con.execute("SELECT COALESCE(MAX(run), 0) FROM results").fetchone()
        self.run = int(row[0]) + 1  # this session's run number

    def _create(self, config_text: str) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".store.", suffix=".sqlite.tmp", dir=self.path.parent)
        os.close(fd)
        try:
            con = sqlite3.connect(tmp)
            con.executescript(_SCHEMA)
            con.execute("INSERT INTO meta VALUES ('config', ?)", (config_text,))
            con.commit()
            con.close()
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def done(self) -> set[str]:
        """Keys of the tasks already stored."""
        return {r[0] for r in self._con.execute("SELECT task FROM results")}

    def add(
        self, task: str, terrain: int, pattern: str, n_swaths: int, payload: dict[str, Any]
    ) -> None:
        """Commit one finished task (ignored if the key is already stored: no duplicates)."""
        with self._con:
            self._con.execute(
                "INSERT OR IGNORE INTO results VALUES (?, ?, ?, ?, ?, ?)",
                (task, terrain, pattern, n_swaths, self.run, json.dumps(payload, sort_keys=True)),
            )

    def rows(self) -> list[dict[str, Any]]:
        """Every stored row, sorted by (pattern, n_swaths, terrain): independent of the order
        in which workers finished."""
        cur = self._con.execute(
            "SELECT terrain, pattern, n_swaths, run, payload FROM results "
            "ORDER BY pattern, n_swaths, terrain"
        )
        return [
            {"terrain": t, "pattern": p, "n_swaths": n, "run": r, **json.loads(payload)}
            for t, p, n, r, payload in cur
        ]

    def runs(self) -> Iterable[tuple[int, int]]:
        """``(run, rows committed in that run)`` — how a resumed sweep split its work."""
        return self._con.execute(
            "SELECT run, COUNT(*) FROM results GROUP BY run ORDER BY run"
        ).fetchall()

    def close(self) -> None:
        self._con.close()

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
