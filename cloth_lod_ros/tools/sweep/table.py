"""The sweep's table: one row per run, streamed as runs finish (``cloth-lod sweep``).

Two formats, both read by pandas (``pd.read_parquet``, ``pd.read_csv``):

* **Parquet** (``sweep.parquet``, when pyarrow is installed): a Parquet file
  cannot be appended to, so the whole table is rewritten - to a temporary
  file in the same folder, then renamed over the old one (``os.replace``,
  atomic on POSIX) - at most every :data:`PARQUET_INTERVAL` seconds while rows
  arrive, and at the end.  A reader, a crash or Ctrl-C therefore always finds
  a complete table; a kill loses at most the last few seconds' rows, which
  ``--resume`` runs again.  One file rather than part files: the table stays
  one file to copy or open (part files need a reader that globs a folder),
  and rewriting it costs milliseconds per thousand rows.
* **CSV** (``sweep.csv``): rows are appended as they land (flushed and
  synced), so the table is complete up to the last finished run.

Cells are plain values; lists and mappings (waypoints, the scene) are JSON
strings.
"""

from __future__ import annotations

import csv
import json
import math
import os
import time as _time
from pathlib import Path

__all__ = ["Table", "PARQUET_INTERVAL", "have_pyarrow", "read_rows", "table_path"]

#: Seconds between rewrites of a Parquet table while rows arrive.
PARQUET_INTERVAL = 2.0


def have_pyarrow() -> bool:
    try:
        import pyarrow.parquet  # noqa: F401
    except ImportError:
        return False
    return True


def table_path(out: Path, fmt: str) -> Path:
    """``out/sweep.parquet`` or ``out/sweep.csv``; ``fmt`` ``auto`` takes an
    existing table first, then Parquet if pyarrow is installed."""
    if fmt == "auto":
        for suffix in ("parquet", "csv"):
            if (out / f"sweep.{suffix}").exists():
                return out / f"sweep.{suffix}"
        fmt = "parquet" if have_pyarrow() else "csv"
    return out / f"sweep.{fmt}"


def _cell(value):
    if isinstance(value, (list, tuple, dict)):
        return json.dumps(value)
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        return value.item()                     # numpy scalars
    return value


def read_rows(path: Path) -> list[dict]:
    """Every row of a table (CSV cells as strings, ``""`` for none)."""
    path = Path(path)
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq
        return pq.read_table(path).to_pylist()
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


class Table:
    """The table of one sweep, created or continued.

    Args:
        path: ``.parquet`` or ``.csv``.
        columns: every column, in order.
        resume: keep the rows already there (their columns must be these).
    """

    def __init__(self, path: Path, columns: list[str], resume: bool):
        self.path = Path(path)
        self.columns = list(columns)
        self.parquet = self.path.suffix == ".parquet"
        self.rows: list[dict] = []
        self._dirty = False
        self._written = 0.0
        if resume and self.path.exists():
            self.rows = read_rows(self.path)
            have = list(self.rows[0]) if self.rows else self._header()
            if have != self.columns:
                missing = [c for c in self.columns if c not in have]
                extra = [c for c in have if c not in self.columns]
                raise ValueError(f"{self.path} has other columns than this sweep (missing "
                                 f"{missing[:5]}, extra {extra[:5]}): was the sweep file "
                                 "changed? Write to another --out")
        else:
            self._rewrite()

    def _header(self) -> list[str]:
        if self.parquet:
            import pyarrow.parquet as pq
            return list(pq.read_schema(self.path).names)
        with self.path.open(newline="") as fh:
            return next(csv.reader(fh), [])

    def done(self, statuses=("ok", "failed")) -> dict[str, dict]:
        """Rows by run id whose status is one of ``statuses`` (the last row of an id wins)."""
        return {r["run_id"]: r for r in self.rows if r.get("status") in statuses}

    def drop(self, run_ids: set[str]) -> None:
        """Remove the rows of these runs (before running them again)."""
        if run_ids:
            self.rows = [r for r in self.rows if r["run_id"] not in run_ids]
            self._rewrite()

    def add(self, row: dict) -> None:
        """Append a row (keys outside the columns are an error; missing ones are empty)."""
        extra = set(row) - set(self.columns)
        if extra:
            raise KeyError(f"not table columns: {sorted(extra)}")
        row = {c: _cell(row.get(c)) for c in self.columns}
        self.rows.append(row)
        if self.parquet:
            self._dirty = True
            if _time.monotonic() - self._written >= PARQUET_INTERVAL:
                self.flush()
        else:
            with self.path.open("a", newline="") as fh:
                csv.writer(fh).writerow([self._csv(row[c]) for c in self.columns])
                fh.flush()
                os.fsync(fh.fileno())

    def flush(self) -> None:
        """Write what is pending (Parquet: the atomic rewrite)."""
        if self.parquet and self._dirty:
            self._rewrite()

    @staticmethod
    def _csv(value):
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return ""
        return repr(value) if isinstance(value, float) else value

    def _rewrite(self) -> None:
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.parquet:
            import pyarrow as pa
            import pyarrow.parquet as pq
            arrays = []
            for c in self.columns:
                values = [r.get(c) for r in self.rows]
                try:
                    arrays.append(pa.array(values))
                except (pa.ArrowInvalid, pa.ArrowTypeError):      # mixed types: as text
                    arrays.append(pa.array([None if v is None else json.dumps(v)
                                            for v in values]))
            pq.write_table(pa.Table.from_arrays(arrays, names=self.columns), tmp)
        else:
            with tmp.open("w", newline="") as fh:
                writer = csv.writer(fh)
                writer.writerow(self.columns)
                for r in self.rows:
                    writer.writerow([self._csv(r.get(c)) for c in self.columns])
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, self.path)
        self._dirty = False
        self._written = _time.monotonic()
