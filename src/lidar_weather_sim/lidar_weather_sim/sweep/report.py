"""A sweep's report: ``report.md`` (what ran, where, how long, failures, per-point means) and one PNG
per metric over the swept keys (mean over seeds with the min-max range; random draws as scatter)."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from lidar_weather_sim.sweep.results import FIRST_COLUMNS, LAST_COLUMNS

MAX_PLOTS = 24


def _numeric(rows: list[dict[str, Any]], key: str) -> np.ndarray:
    out = []
    for row in rows:
        try:
            out.append(float(row.get(key, "nan")))
        except (TypeError, ValueError):
            out.append(float("nan"))
    return np.asarray(out)


def metric_columns(rows: list[dict[str, Any]], swept: list[str]) -> list[str]:
    skip = {*FIRST_COLUMNS, *LAST_COLUMNS, *swept}
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in skip and k not in keys]
    return [k for k in sorted(keys) if np.isfinite(_numeric(rows, k)).any()]


def _plot(rows: list[dict[str, Any]], swept: list[str], metric: str, path: Path, grid: bool) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, max(1, len(swept)), figsize=(4.2 * max(1, len(swept)), 3.2), squeeze=False)
    y = _numeric(rows, metric)
    for ax, key in zip(axes[0], swept or ["seed"]):
        x = _numeric(rows, key)
        if not np.isfinite(x).any():  # categorical values: their order of appearance
            names = list(dict.fromkeys(str(r.get(key)) for r in rows))
            x = np.array([names.index(str(r.get(key))) for r in rows], float)
            ax.set_xticks(range(len(names)), names)
        if grid:
            groups: dict[float, list[float]] = defaultdict(list)
            for xi, yi in zip(x, y):
                if np.isfinite(yi):
                    groups[xi].append(yi)
            xs = np.array(sorted(groups))
            mean = np.array([np.mean(groups[v]) for v in xs])
            err = np.array([[mean[i] - min(groups[v]), max(groups[v]) - mean[i]] for i, v in enumerate(xs)]).T
            ax.errorbar(xs, mean, yerr=err if len(xs) else None, marker="o", capsize=3)
        else:
            ax.scatter(x, y, s=14)
        ax.set_xlabel(key)
        ax.set_ylabel(metric)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_report(out: Path, rows: list[dict[str, Any]], swept: list[str], *, grid: bool, engine: str,
                 wall_s: float, skipped: int) -> Path:  # fmt: skip
    """``out/report.md`` and ``out/plots/<metric>.png``; returns the report's path."""
    ok = [r for r in rows if r.get("status") == "ok"]
    failed = [r for r in rows if r.get("status") != "ok"]
    metrics = metric_columns(ok, swept)
    plots = out / "plots"
    plots.mkdir(exist_ok=True)
    for metric in metrics[:MAX_PLOTS]:
        _plot(ok, swept, metric, plots / f"{metric.replace('/', '_')}.png", grid)
    run_time = sum(float(r.get("elapsed_s") or 0) for r in rows)
    lines = [
        "# Sweep report", "",
        f"- runs: {len(rows)} ({len(ok)} ok, {len(failed)} failed; {skipped} already in this directory, not run again)",
        f"- engine: {engine}; wall time {wall_s:.1f} s; run time summed over runs {run_time:.1f} s",
        f"- swept: {', '.join(swept) or 'seeds only'}", "",
    ]  # fmt: skip
    if failed:
        lines += ["## Failed runs", "", *(f"- `{r['run_id']}` (seed {r.get('seed')}, "
                                         f"{', '.join(f'{k}={r.get(k)}' for k in swept)}): {r.get('error')}"
                                         for r in failed), ""]  # fmt: skip
    shown = metrics[:8]
    if ok and shown:
        lines += ["## Mean over seeds", "", "| " + " | ".join([*swept, "runs", *shown]) + " |",
                  "|" + "---|" * (len(swept) + 1 + len(shown))]  # fmt: skip
        groups: dict[tuple, list[dict]] = defaultdict(list)
        for r in ok:
            groups[tuple(str(r.get(k)) for k in swept)].append(r)
        for key, members in groups.items():
            means = [np.nanmean(_numeric(members, m)) if np.isfinite(_numeric(members, m)).any() else math.nan
                     for m in shown]  # fmt: skip
            lines.append("| " + " | ".join([*key, str(len(members)), *(f"{v:.4g}" for v in means)]) + " |")
        lines.append("")
    lines += ["## Plots", "", *(f"![{m}](plots/{m.replace('/', '_')}.png)" for m in metrics[:MAX_PLOTS]), ""]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path
