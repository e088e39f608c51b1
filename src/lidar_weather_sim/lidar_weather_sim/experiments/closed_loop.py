"""Closed-loop demo: adaptive cruise on the LiDAR cloud, with and without the weather filter, with and without a box.

Each variant runs the graph ``config/graphs/closed_loop.yaml`` (lidar_sim_node
in scenario mode -> [weather_filter_node] -> ego_controller_node ->
/ego/cmd_speed -> the scenario player) as separate processes over DDS for a
number of simulated seconds; the controller writes its per-cloud trace. The
box variants add a static box (label obstacle) in the ego's lane that appears
at ``box_at_s``, ``box_ahead_m`` ahead of where the ego would be by then.
"Brakes" is fixed in :mod:`lidar_weather_sim.control.acc` (commanded deceleration
> 2 m/s^2 for >= 0.3 s). The report (report.md, speed.png, the traces) goes to ``out``.
The graph runs in synchronous mode (:mod:`lidar_weather_sim.ros.sync`): the traces are the same
on a fast, a slow and a loaded machine. The expected table: without the filter the spray makes
the ego brake; with the filter it does not; with a box in the lane it brakes either way.
:func:`main` exits 1 when a variant differs from it.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from lidar_weather_sim.control.acc import BRAKE_DECEL_M_S2, BRAKE_MIN_DURATION_S, braking_events
from lidar_weather_sim.ros.graph import load_graph, resolve, run
from lidar_weather_sim.scenario.schema import load_scenario, scenario_path
from lidar_weather_sim.sensor.profile import load_profile

BOX_ID = 900
BOX_SIZE = {"length_m": 1.0, "width_m": 1.6, "height_m": 1.2}


@dataclass(frozen=True)
class Variant:
    name: str
    filter: bool
    box: bool

    @property
    def should_brake(self) -> bool:
        """The expected outcome: brakes for a box, and for the spray unless the filter removes it."""
        return self.box or not self.filter


VARIANTS = (Variant("no filter", False, False), Variant("filter", True, False),
            Variant("no filter + box", False, True), Variant("filter + box", True, True))  # fmt: skip


@dataclass
class Trace:
    variant: Variant
    stamp_s: np.ndarray
    distance_m: np.ndarray  # NaN: no obstacle
    speed_m_s: np.ndarray
    label: np.ndarray  # ground-truth label most common in the obstacle cluster (NaN: none or unlabelled)
    exit_status: int

    @property
    def events(self) -> list[tuple[float, float]]:
        return braking_events(self.stamp_s, self.speed_m_s)

    @property
    def brakes(self) -> bool:
        return bool(self.events)


def box_scenario(scenario: str, box_at_s: float, box_ahead_m: float, out_dir: Path) -> Path:
    """A copy of ``scenario`` with a static box in the ego's lane appearing at ``box_at_s`` (YAML path)."""
    data = yaml.safe_load(scenario_path(scenario).read_text())
    ego = load_scenario(scenario).ego
    s_m = ego.s_m + ego.speed_m_s * box_at_s + box_ahead_m
    data["name"] = f"{data['name']}_box"
    data["actors"] = [*data.get("actors", []), {
        "id": BOX_ID, "type": "box", "label": "obstacle", "road": ego.road, "lane": ego.lane, "s_m": float(s_m),
        "speed_m_s": 0.0, "size": BOX_SIZE, "appear_s": float(box_at_s),
    }]  # fmt: skip
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{data['name']}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def read_trace(path: Path, variant: Variant, status: int) -> Trace:
    rows = list(csv.DictReader(path.open())) if path.exists() else []
    col = lambda key: np.array([float(r[key]) if r[key] else np.nan for r in rows])  # noqa: E731
    return Trace(variant, col("stamp_s"), col("distance_m"), col("cmd_speed_m_s"), col("label"), status)


def run_variant(variant: Variant, scenario: str, seconds: float, out: Path, *, box_at_s: float = 3.0,
                box_ahead_m: float = 50.0, realtime_factor: float = 1.0, synchronous: bool = True,
                emit=None) -> Trace:  # fmt: skip
    """Run one variant over DDS; returns the controller's trace."""
    slug = variant.name.replace(" + ", "_").replace(" ", "_")
    scen = str(box_scenario(scenario, box_at_s, box_ahead_m, out)) if variant.box else scenario
    frames = int(round(seconds / load_profile(load_scenario(scenario).sensor.profile).period_s))
    trace = out / f"trace_{slug}.csv"
    trace.unlink(missing_ok=True)
    args = {"scenario": scen, "filter": str(variant.filter).lower(), "max_frames": str(frames),
            "realtime_factor": str(realtime_factor), "trace_csv": str(trace),
            "synchronous": str(synchronous).lower()}  # fmt: skip
    log = (out / f"log_{slug}.txt").open("w")
    try:
        status = run(resolve(load_graph("closed_loop"), args), out / f"run_{slug}", emit=lambda s: log.write(s + "\n"))
    finally:
        log.close()
    result = read_trace(trace, variant, status)
    if emit:
        emit(f"{variant.name}: {len(result.stamp_s)} commands, brakes={result.brakes}, min speed {np.nanmin(result.speed_m_s, initial=np.inf):.2f} m/s")
    return result


def write_report(traces: list[Trace], scenario: str, out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for tr in traces:
        if len(tr.stamp_s):
            ax.plot(tr.stamp_s - tr.stamp_s[0], tr.speed_m_s, label=f"{tr.variant.name}{' (brakes)' if tr.brakes else ''}")
    ax.set_xlabel("simulated time since first command (s)")
    ax.set_ylabel("commanded speed (m/s)")
    ax.set_title(f"adaptive cruise on {scenario}")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "speed.png", dpi=110)
    plt.close(fig)
    lines = [f"# Closed loop on `{scenario}`", "",
             f"Brakes = commanded deceleration > {BRAKE_DECEL_M_S2:g} m/s^2 for >= {BRAKE_MIN_DURATION_S:g} s.", "",
             "| variant | commands | brakes | braking events (s, from first command) | frames with obstacle | obstacle labels (frames) | min speed (m/s) | exit |",
             "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for tr in traces:
        t0 = tr.stamp_s[0] if len(tr.stamp_s) else 0.0
        events = ", ".join(f"{a - t0:.2f}-{b - t0:.2f}" for a, b in tr.events) or "-"
        seen = int(np.isfinite(tr.distance_m).sum())
        vmin = f"{np.nanmin(tr.speed_m_s):.2f}" if len(tr.speed_m_s) else "-"
        codes, counts = np.unique(tr.label[np.isfinite(tr.label)].astype(int), return_counts=True)
        labels = ", ".join(f"{c}: {n}" for c, n in zip(codes, counts)) or "-"
        lines.append(f"| {tr.variant.name} | {len(tr.stamp_s)} | {'yes' if tr.brakes else 'no'} | {events} | {seen} | {labels} | {vmin} | {tr.exit_status} |")
    lines += ["", "Labels: 1 static scene, 2 vehicle, 3 obstacle, 10 cover, 11 rain, 12 fog, 13 snow, 14 spray, 15 noise.",
              "", "![speed traces](speed.png)", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path


def main(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    traces = [run_variant(v, args.scenario, args.seconds, out, box_at_s=args.box_at,
                          realtime_factor=args.realtime_factor, synchronous=not args.free_running,
                          emit=print) for v in VARIANTS]  # fmt: skip
    print(f"report: {write_report(traces, args.scenario, out)}")
    wrong = unexpected(traces)
    for line in wrong:
        print(f"closed-loop: {line}")
    return 1 if wrong else 0


def unexpected(traces: list[Trace]) -> list[str]:
    """One line per variant that failed or whose braking differs from :attr:`Variant.should_brake`."""
    lines = []
    for tr in traces:
        if tr.exit_status != 0 or not len(tr.stamp_s):
            lines.append(f"{tr.variant.name}: the graph exited with status {tr.exit_status} after "
                         f"{len(tr.stamp_s)} commands (its log: log_*.txt in the report directory)")  # fmt: skip
        elif tr.brakes != tr.variant.should_brake:
            lines.append(f"{tr.variant.name}: {'brakes' if tr.brakes else 'does not brake'}, expected "
                         f"{'braking' if tr.variant.should_brake else 'no braking'}")  # fmt: skip
    return lines
