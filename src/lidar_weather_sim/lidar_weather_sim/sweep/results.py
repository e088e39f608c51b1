"""A sweep's rows on disk: ``rows.jsonl`` (appended and flushed as each run ends, so a killed
sweep loses no finished run) and ``results.csv`` (one row per run of the sweep, in run order).

``rows.jsonl`` may hold rows of runs of earlier sweeps into the same directory; the last row
of a run wins (a failed run that is re-run on resume is replaced by its new row)."""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path
from typing import Any

ROWS = "rows.jsonl"
RESULTS = "results.csv"
FIRST_COLUMNS = ("run_id", "seed")
LAST_COLUMNS = ("status", "note", "elapsed_s", "error")


class ResultStore:
    def __init__(self, out: str | Path) -> None:
        self.out = Path(out)

    def rows(self) -> dict[str, dict[str, Any]]:
        """run_id -> its last row; a truncated last line (a killed writer) is ignored."""
        path = self.out / ROWS
        if not path.exists():
            return {}
        found: dict[str, dict[str, Any]] = {}
        for line in path.read_text().splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(row, dict) and "run_id" in row:
                found[row["run_id"]] = row
        return found

    def finished(self) -> set[str]:
        """Runs that ended well: skipped on resume (failed runs are run again)."""
        return {run_id for run_id, row in self.rows().items() if row.get("status") == "ok"}

    def add(self, row: dict[str, Any]) -> None:
        with open(self.out / ROWS, "a") as f:
            f.write(json.dumps(row, sort_keys=True, default=_json_value) + "\n")
            f.flush()
            os.fsync(f.fileno())

    def write_csv(self, rows: list[dict[str, Any]], swept: list[str]) -> Path:
        metrics: list[str] = []
        for row in rows:
            metrics += [k for k in row if k not in metrics]
        fixed = [*FIRST_COLUMNS, *swept, *LAST_COLUMNS]
        columns = [*FIRST_COLUMNS, *swept, *sorted(k for k in metrics if k not in fixed), *LAST_COLUMNS]
        path = self.out / RESULTS
        with open(path, "w", newline="") as f:
            writer = csv.DictWriter(f, columns, restval="")
            writer.writeheader()
            writer.writerows({k: row.get(k, "") for k in columns} for row in rows)
        return path


def _json_value(value: Any) -> Any:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return str(value)
    return number if math.isfinite(number) else None


def read_csv(path: str | Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
