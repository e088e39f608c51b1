"""``lidar-weather-sim reproduce rooftop``: the thesis' rooftop experiment (paper 2) in simulation.

Simulates clear, rain, fog and snow, each with and without sun, on the rooftop
scene (:mod:`lidar_weather_sim.experiments.rooftop`, scenario ``config/scenarios/rooftop_static.yaml``) with each
weather class's state (weather, street, window) from ``config/rooftop_physical.yaml``
(:mod:`lidar_weather_sim.experiments.rooftop_states`),
computes the 12 per-frame parameters (:mod:`lidar_weather_sim.core.frame_parameters`) in the
atmosphere (0-5 m) and street (33-37 m) regions and for both together, and
compares them with the paper's Tables 2-4 (read from thesis_tables.yaml).

Output in ``DIR``: ``rooftop.json`` (rows: weather, sun, region, parameter, unit,
sim_mean, sim_std, paper_mean, paper_std), ``rooftop.md`` (the same as a table
with a within-1-sigma flag) and ``rooftop_atmosphere.png`` / ``rooftop_street.png``
(histograms over all frames, 5 cm bins, like the paper's Figs. 5 and 6).
Units are the paper's: x_sigma in cm, street x_mean in cm after subtracting 34 m,
other distances and EPW in m.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from lidar_weather_sim.experiments.rooftop import (ATMOSPHERE_REGION_M, STREET_REGION_X_M, RooftopPose,
                                                   bounded_lot_scene, geometry)  # fmt: skip
from lidar_weather_sim.experiments.rooftop_states import WEATHER_CLASSES, RooftopStates, load_states
from lidar_weather_sim.core.frame_parameters import FEATURES, UNITS, frame_features, summarize
from lidar_weather_sim.regions.base import REGISTRY, RegionContext
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.scene.materials import MaterialTable
from lidar_weather_sim.scene.scene import Scene
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.sim.simulator import LidarSimulator

REGIONS = {"atmosphere": ATMOSPHERE_REGION_M, "street": STREET_REGION_X_M}
STREET_OFFSET_M = 34.0
#: thesis_tables key per (region, feature) and the factor/offset to the paper's unit
PAPER_KEYS = {
    "atmosphere": {"n_total": "n_total", "n_peak": "n_peak", "x_sigma": "x_sigma_cm", "n_e1": "n_e1", "epw_mean": "epw_m"},
    "street": {"n_peak": "n_peak", "x_mean": "x_mean_cm_minus_34m", "x_sigma": "x_sigma_cm", "n_e2": "n_e2", "epw_mean": "epw_m"},
    "both": {"n_e1": "n_e1", "n_e2": "n_e2", "epw_mean": "epw_m"},
}


#: thesis_tables.yaml sections the comparison reads (paper 2 Tables 2, 3 and 4)
TABLE_SECTIONS = ("background_radiation_clear", "atmosphere_region", "street_region")


def load_tables(path: str | Path | None = None) -> dict:
    """The thesis' measured values (``thesis_tables.yaml``), checked for the sections the comparison reads."""
    path = Path(path or default_tables_path())
    tables = yaml.safe_load(path.read_text())
    missing = [k for k in TABLE_SECTIONS if not isinstance(tables, dict) or k not in tables]
    if missing:
        raise ValueError(f"{path}: not the thesis tables (no section {', '.join(missing)})")
    return tables


def default_tables_path() -> Path:
    from lidar_weather_sim.core.paths import config_dir

    return config_dir().parent.parent / "shared" / "data" / "thesis_tables.yaml"


LOT_MATERIAL = "asphalt_rooftop"


def lot_scene(materials: MaterialTable | None = None, street_gain: float | None = None) -> Scene:
    """The asphalt the sensor sees (config/rooftop.yaml ``lot``) at z = 0.

    Its material is ``asphalt_dry`` (albedo 0.12, paper 2) with a retro-reflective share chosen so
    that its backscatter at 46 deg is ``street_gain`` times the Lambertian one (None: config/rooftop.yaml's):
    the paper's 0.12 is a broadband (solar) albedo [43], not the 905 nm backscatter.
    """
    street_gain = geometry().street_gain if street_gain is None else street_gain
    from lidar_weather_sim.scene.mesh import Material
    from lidar_weather_sim.sensor.radiometry import RETRO_GAIN

    materials = materials or MaterialTable.default()
    dry = materials["asphalt_dry"]
    cos_ref = float(np.cos(np.deg2rad(46.0)))
    retro = float(np.clip(cos_ref * (street_gain - 1.0) / (RETRO_GAIN - cos_ref), 0.0, 1.0))
    if LOT_MATERIAL not in materials:
        materials = MaterialTable([*materials.materials, Material(LOT_MATERIAL, dry.reflectivity, retro, dry.label)])
    return bounded_lot_scene(LOT_MATERIAL, materials)


@dataclass
class Condition:
    weather: str
    sun: bool
    frames: list[dict[str, dict[str, float]]]  # per frame: region -> features
    x: dict[str, np.ndarray]  # region -> all x distances (m) over the frames


def simulate(weather_class: str, sun: bool, frames: int, seed: int = 0, scenario: str = "rooftop_static",
             profile: str | None = None, states: RooftopStates | None = None) -> Condition:  # fmt: skip
    """Per-frame features of one condition: the weather, street and window of the class from ``states`` (default
    config/rooftop_physical.yaml, :mod:`lidar_weather_sim.experiments.rooftop_states`); ``profile`` (a name in
    config/sensors or a YAML path) replaces the scenario's sensor, e.g. to see how its noise model acts on the
    'with sun' rows."""
    sc = load_scenario(scenario)
    profile = load_profile(profile or sc.sensor.profile)
    scene = lot_scene(MaterialTable.default())
    states = states or load_states()
    context = RegionContext(profile, states.weather(weather_class), scene.materials)
    regions = []
    for name in sc.regions:
        params = dict(sc.region_params.get(name, {}))
        if name == "cover":
            params.update(states.cover_params(weather_class))
        regions.append((name, REGISTRY.create(name, params, context)))
    day = states.day_irradiance_w_m2
    sim = LidarSimulator(profile, scene, regions=regions, seed=seed, sun_irradiance_w_m2=day if sun else 0.0)
    pose = RooftopPose.for_profile(profile)
    out, t = [], 0.0
    while len(out) < frames:
        out += sim.advance(t, pose)
        t += 0.01
    rows, xs = [], {k: [] for k in REGIONS}
    for frame in out[:frames]:
        p = frame.points
        x = pose.x_distance(p).astype(np.float64)
        row = {name: frame_features(x, p["echo"], p["epw"], *bounds) for name, bounds in REGIONS.items()}
        both = ((x >= REGIONS["atmosphere"][0]) & (x < REGIONS["atmosphere"][1])) | \
               ((x >= REGIONS["street"][0]) & (x < REGIONS["street"][1]))  # fmt: skip
        row["both"] = frame_features(np.where(both, 0.0, -1.0), p["echo"], p["epw"], 0.0, 1.0)
        rows.append(row)
        for name, (lo, hi) in REGIONS.items():
            xs[name].append(x[(x >= lo) & (x < hi)])
    return Condition(weather_class, sun, rows, {k: np.concatenate(v) for k, v in xs.items()})


def to_paper_units(region: str, feature: str, value: float) -> tuple[float, str]:
    if feature == "x_sigma":
        return value * 100.0, "cm"
    if region == "street" and feature == "x_mean":
        return (value - STREET_OFFSET_M) * 100.0, "cm (x - 34 m)"
    return value, UNITS[feature]


def paper_value(tables: dict, region: str, feature: str, weather: str, sun: bool):
    key = PAPER_KEYS.get(region, {}).get(feature)
    if key is None:
        return None
    if region == "both":
        if weather != "clear":
            return None
        return tables["background_radiation_clear"]["day" if sun else "night"][key]
    table = tables["atmosphere_region" if region == "atmosphere" else "street_region"]
    return table[key][weather]["sun_true" if sun else "sun_false"]


def rows_of(cond: Condition, tables: dict) -> list[dict]:
    out = []
    for region in ("atmosphere", "street", "both"):
        stats = summarize([f[region] for f in cond.frames])
        features = FEATURES if region != "both" else ("n_total", "n_e1", "n_e2", "n_e3", "epw_mean", "epw_std")
        for feature in features:
            mean, std = stats[feature]
            m, unit = to_paper_units(region, feature, mean)
            s = std * (100.0 if feature in ("x_sigma", "x_mean") and unit.startswith("cm") else 1.0)
            paper = paper_value(tables, region, feature, cond.weather, cond.sun)
            out.append({"weather": cond.weather, "sun": cond.sun, "region": region, "parameter": feature, "unit": unit,
                        "sim_mean": _num(m), "sim_std": _num(s),
                        "paper_mean": None if paper is None else float(paper[0]),
                        "paper_std": None if paper is None else float(paper[1])})  # fmt: skip
    return out


def _num(v: float):
    return None if not np.isfinite(v) else round(float(v), 4)


def within_sigma(row: dict) -> bool | None:
    if row["paper_mean"] is None or row["sim_mean"] is None:
        return None
    return abs(row["sim_mean"] - row["paper_mean"]) <= row["paper_std"]


def markdown(rows: list[dict]) -> str:
    lines = ["| weather | sun | region | parameter | unit | sim | paper | within 1 sigma |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        sim = "n/a" if r["sim_mean"] is None else f"{r['sim_mean']:.3g} ± {r['sim_std']:.2g}"
        paper = "" if r["paper_mean"] is None else f"{r['paper_mean']:.3g} ± {r['paper_std']:.2g}"
        flag = {None: "", True: "yes", False: "**no**"}[within_sigma(r)]
        lines.append(f"| {r['weather']} | {'w' if r['sun'] else 'w/o'} | {r['region']} | {r['parameter']} | {r['unit']} | "
                     f"{sim} | {paper} | {flag} |")  # fmt: skip
    compared = [within_sigma(r) for r in rows if within_sigma(r) is not None]
    tables_3_4 = [within_sigma(r) for r in rows if r["region"] != "both" and within_sigma(r) is not None]
    lines.append(f"\n{sum(compared)} of {len(compared)} paper means matched within ±1 sigma "
                 f"({sum(tables_3_4)} of {len(tables_3_4)} of Tables 3-4, the regions; the rest are Table 2's).")
    return "\n".join(lines) + "\n"


def plot(conditions: list[Condition], out_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    for region, (lo, hi) in REGIONS.items():
        fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
        bins = np.arange(lo, hi + 1e-9, 0.05)
        for ax, sun in zip(axes, (False, True)):
            for c in conditions:
                if c.sun == sun and len(c.x[region]):
                    ax.hist(c.x[region], bins=bins, histtype="step", label=f"{c.weather} (x_sigma {100 * c.x[region].std():.0f} cm)")
            ax.set_title(f"{region} region, {'with' if sun else 'without'} sun")
            ax.set_xlabel("x distance (m)")
            if region == "atmosphere":
                ax.set_yscale("log")
            ax.legend(fontsize=8)
        axes[0].set_ylabel(f"detections per 5 cm bin ({len(conditions[0].frames)} frames)")
        path = out_dir / f"rooftop_{region}.png"
        fig.tight_layout()
        fig.savefig(path, dpi=100)
        plt.close(fig)
        paths.append(path)
    return paths


def reproduce_rooftop(out_dir: str | Path, frames: int = 30, seed: int = 0, tables_path: str | Path | None = None,
                      plots: bool = True, profile: str | None = None, states_file: str | None = None) -> list[dict]:  # fmt: skip
    """Run all 8 conditions; write rooftop.json, rooftop.md and the PNGs into ``out_dir``; return the rows.
    ``profile``: sensor profile name or YAML path (default the scenario's scala4); ``states_file``: the weather,
    street and window states (default config/rooftop_physical.yaml)."""
    tables = load_tables(tables_path)
    states = load_states(states_file)
    conditions = [simulate(w, sun, frames, seed, profile=profile, states=states)
                  for w in WEATHER_CLASSES for sun in (False, True)]  # fmt: skip
    rows = [r for c in conditions for r in rows_of(c, tables)]
    out = Path(out_dir)  # created once the inputs have loaded: bad inputs leave nothing behind
    out.mkdir(parents=True, exist_ok=True)
    (out / "rooftop.json").write_text(json.dumps(rows, indent=1))
    (out / "rooftop.md").write_text(markdown(rows))
    if plots:
        plot(conditions, out)
    return rows


def main(args) -> int:
    """CLI entry (``lidar-weather-sim reproduce rooftop``): run, print the Markdown table, return 0."""
    import time

    start = time.perf_counter()
    rows = reproduce_rooftop(args.out, frames=args.frames, seed=args.seed, tables_path=args.tables,
                             profile=args.profile, states_file=args.states)  # fmt: skip
    print(markdown(rows))
    print(f"wrote {args.out}/rooftop.json, rooftop.md, rooftop_atmosphere.png, rooftop_street.png "
          f"in {time.perf_counter() - start:.1f} s")  # fmt: skip
    return 0
