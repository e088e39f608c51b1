#!/usr/bin/env python3
"""Does `gap --effects sensor` find a sensor-side effect hidden in a re-simulation of a real recording?

    python benchmarks/validation/sensor_effect_recovery.py [--cases FILE] [--scenario TWIN_DIR/scenario.yaml] [--limit K]
        [--profiles P,...] [--effects E,...] [--only K,...] [--workers N] [--progress]

The cases are config/sensor_effect_cases.yaml's seeded draws (committed before any run): for each
profile and sensor effect, ``draws_per_effect`` values of its main parameter, plus ``clear_cases``
re-simulations with nothing hidden. Each case re-simulates the real OS1-128 recording's frames
(.venv/cache/ouster_real/os1_128_street: its poses and stamps) in SCENARIO (default ``ouster_street``,
Ouster's mesh; a `lidar-weather-sim twin` directory's scenario for the twin) with the profile and
the hidden effect, writes that as the "measured" bag, and runs the gap search (sensor family only,
the file's budgets) against SCENARIO with the same profile. Every case is printed: the hidden effect,
what was named, the parameter error, the held-out gap before and after. A case is right when exactly
the hidden effect is named and its main parameter is within ``parameter_within`` (range bias: or 1 cm);
a clear case is right when nothing is named. Case k is simulated with seed 1000 + k.

``--cases config/channel_effect_cases.yaml``: the per-channel effects read off the data (weak channels,
elevation offsets): each draw hides its values on randomly drawn channels; right when exactly that effect is
named on exactly those channels, each value within ``parameter_within`` (offsets: or ``offset_within_deg``).
``--cases config/enumerated_effect_cases.yaml``: dead channels (right on exactly the drawn channels) and the
return mode (right with exactly the drawn mode).

A missed draw whose effect changes no point of the re-simulation (every field but ``return_type``) is marked
so, and the total is also given without such draws: they are not misses of the search.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[2]
CASES = ROOT / "config" / "sensor_effect_cases.yaml"
MEASURED_SEED = 1000  # case k is drawn with seed 1000 + k: never the search's own draws (the scenario's seed, + 7919)


def draw_cases(spec: dict) -> list[tuple[str, str | None, float | str | None]]:
    """(profile, effect name or None for a clear case, main value: a number, or for a per-channel effect its
    ``channel:value`` text) in the file's seeded order."""
    if "channel_effects" in spec:
        return draw_channel_cases(spec)
    rng = np.random.default_rng(spec["seed"])
    values = {}
    for name, entry in spec["effects"].items():
        (lo, hi), scale = entry["range"], entry["scale"]
        n = spec["draws_per_effect"] * len(spec["profiles"])
        values[name] = np.exp(rng.uniform(np.log(lo), np.log(hi), n)) if scale == "log" else rng.uniform(lo, hi, n)
    cases = []
    for p, profile in enumerate(spec["profiles"]):
        for name, drawn in values.items():
            k = spec["draws_per_effect"]
            cases += [(profile, name, float(v)) for v in drawn[p * k : (p + 1) * k]]
        cases += [(profile, None, None)] * spec["clear_cases"]
    return cases


def draw_channel_cases(spec: dict) -> list[tuple[str, str | None, str | None]]:
    """The per-channel draws (``channel_effects``): channels uniformly from the profile's, values as the entry says."""
    from lidar_weather_sim.scenario.effects import format_channel_values
    from lidar_weather_sim.sensor.profile import load_profile

    rng = np.random.default_rng(spec["seed"])
    cases = []
    for profile in spec["profiles"]:
        n_channels = len(load_profile(profile).beams)
        for name, entry in spec["channel_effects"].items():
            k = entry["channels"]
            for _ in range(spec["draws_per_effect"]):
                channels = rng.choice(n_channels, k, replace=False)
                if "range" not in entry:  # dead channels: the channels alone
                    cases.append((profile, name, "+".join(map(str, sorted(channels.tolist())))))
                    continue
                lo, hi = entry["range"]
                u = rng.uniform(np.log(lo), np.log(hi), k) if entry["scale"] == "log" else rng.uniform(lo, hi, k)
                values = np.exp(u) if entry["scale"] == "log" else u
                if entry.get("signed"):
                    values = values * rng.choice([-1.0, 1.0], k)
                cases.append((profile, name, format_channel_values(dict(zip(channels.tolist(), np.round(values, 4))))))
        for name, entry in spec.get("choice_effects", {}).items():
            cases += [(profile, name, str(rng.choice(entry["choices"]))) for _ in range(spec["draws_per_effect"])]
        cases += [(profile, None, None)] * spec["clear_cases"]
    return cases


def channel_error(name: str, hidden: str, named: str, success: dict) -> tuple[float, bool]:
    """(largest relative error, right) of a per-channel effect named as ``named`` against ``hidden``."""
    from lidar_weather_sim.scenario.effects import parse_channel_values

    if name == "sensor.dead_channels":
        return 0.0, set(hidden.split("+")) == set(named.split("+"))
    want, got = parse_channel_values(name, hidden), parse_channel_values(name, named)
    if set(want) != set(got):
        return float("inf"), False
    errors = [abs(got[c] - v) / abs(v) for c, v in want.items()]
    slack = success.get("offset_within_deg", 0.0) if name == "sensor.elevation_offsets" else 0.0
    ok = all(e <= success["parameter_within"] or abs(got[c] - v) <= slack for e, (c, v) in zip(errors, want.items()))
    return max(errors), ok


def resimulate(recording_path: Path, scenario, profile: str, effects, out: Path, seed: int) -> None:
    """The recording's frames cast again in ``scenario`` + ``effects`` with ``profile``, written as a bag
    with the recording's /tf, /tf_static and /clock."""
    from lidar_weather_sim.core.names import TOPIC_CLOCK, TOPIC_TF, TOPIC_TF_STATIC
    from lidar_weather_sim.replay import Resimulator
    from lidar_weather_sim.io.bags import BagWriter, read_messages
    from lidar_weather_sim.io.recording import Recording

    recording = Recording.load(recording_path)
    resim = Resimulator(recording, scenario.model_copy(update={"seed": seed}), profile)
    frames = resim.frames(effects, range(len(recording.frames)))
    with BagWriter(out, overwrite=True) as bag:
        for m in read_messages(recording_path, [TOPIC_CLOCK, TOPIC_TF, TOPIC_TF_STATIC]):
            bag.write(m.topic, m.msg, m.log_time_ns)
        for frame, points in zip(recording.frames, frames):
            bag.write_cloud(recording.topic, points, frame.stamp_ns, frame.frame_id, log_time_ns=frame.log_time_ns)


def changes_nothing(recording_path: Path, scenario, profile: str, effects, seed: int) -> bool:
    """Whether ``effects`` leave every re-simulated frame as it is without them, point for point in every
    field but ``return_type`` (the driver's label of the mode, which no recording's geometry shows): such a draw
    is one no search can name (a ``dual`` return where no beam has a third echo is ``all``)."""
    from lidar_weather_sim.replay import Resimulator
    from lidar_weather_sim.io.recording import Recording

    recording = Recording.load(recording_path)
    resim = Resimulator(recording, scenario.model_copy(update={"seed": seed}), profile)
    frames = range(len(recording.frames))
    for a, b in zip(resim.frames(effects, frames), resim.frames([], frames)):
        fields = [f for f in a.dtype.names if f != "return_type"]
        if len(a) != len(b) or any(not np.array_equal(a[f], b[f]) for f in fields):
            return False
    return True


def print_step(message: str, casts: int) -> None:
    print(f"      [{casts} casts] {message}", flush=True)


def main() -> None:
    from lidar_weather_sim.core.paths import cache_dir
    from lidar_weather_sim.gap.command import run_gap
    from lidar_weather_sim.scenario.effects import EFFECTS, Effect
    from lidar_weather_sim.gap.report import format_params
    from lidar_weather_sim.scenario.schema import load_scenario

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=str(CASES), help="the committed draws (default: config/sensor_effect_cases.yaml)")
    parser.add_argument("--scenario", default="ouster_street", help="the twin's scenario (default: Ouster's mesh)")
    parser.add_argument("--recording", default=str(cache_dir() / "ouster_real" / "os1_128_street"))
    parser.add_argument("--limit", type=int, default=0, help="run only the first K draws of each profile and effect "
                                                            "(0: all)")
    parser.add_argument("--profiles", help="comma-separated: only the cases of these profiles (default: all)")
    parser.add_argument("--effects", help="comma-separated: only the cases hiding these effects (default: all, and "
                                          "the clear cases)")
    parser.add_argument("--only", help="comma-separated case numbers: run only these (numbered as in a run with the same --profiles)")
    parser.add_argument("--workers", type=int, default=0, help="the gap search's Dask workers (0: in this process)")
    parser.add_argument("--progress", action="store_true", help="print the gap search's steps of every case")
    args = parser.parse_args()
    cases_path = Path(args.cases)
    spec = yaml.safe_load(cases_path.read_text())
    scenario = load_scenario(args.scenario)
    cases = draw_cases(spec)
    if args.profiles:
        cases = [c for c in cases if c[0] in args.profiles.split(",")]
    numbered = list(enumerate(cases))  # a case keeps its number (and so its seed) under --effects and --limit
    if args.effects:
        numbered = [(k, c) for k, c in numbered if c[1] in args.effects.split(",")]
    if args.only:
        numbered = [(k, c) for k, c in numbered if k in {int(x) for x in args.only.split(",")}]
    if args.limit:  # the first K draws of each profile and effect (and K clear cases)
        numbered = [(k, c) for i, (k, c) in enumerate(numbered)
                    if sum(d[:2] == c[:2] for _, d in numbered[:i]) < args.limit]  # fmt: skip
    budgets = {k: spec["measurement"][k] for k in ("fit_frames", "heldout_frames", "screen_frames")}
    within = spec["success"]["parameter_within"]
    print(f"{len(numbered)} cases from {cases_path.name} (seed {spec['seed']}), scenario {scenario.name}, recording "
          f"{args.recording}, budgets {budgets}")  # fmt: skip
    print(f"{'#':>3} {'profile':13} {'hidden':32} {'err':>7} {'gap before -> after':>20} ok  named")
    right: dict[str, list[bool]] = {}
    unchanged: list[int] = []
    with tempfile.TemporaryDirectory(prefix="sensor-effects-") as tmp:
        for k, (profile, name, value) in numbered:
            start = time.perf_counter()
            hidden = [Effect(name, {EFFECTS[name].main: value})] if name else []
            measured = Path(tmp) / f"case{k}"
            resimulate(Path(args.recording), scenario, profile, hidden, measured, seed=MEASURED_SEED + k)
            result = run_gap(measured, scenario, Path(tmp) / f"gap{k}", profile=profile, families=("sensor",),
                             workers=args.workers, progress=print_step if args.progress else None, **budgets)  # fmt: skip
            named = {e["name"]: e["params"] for e in result["effects"]}
            error = None
            if name and name in named and EFFECTS[name].from_data:
                error, ok = channel_error(name, value, str(named[name][EFFECTS[name].main]), spec["success"])
                ok = ok and list(named) == [name]
            elif name and name in named and EFFECTS[name].categorical:
                ok = list(named) == [name] and named[name][EFFECTS[name].main] == value
            elif name and name in named:
                got = named[name][EFFECTS[name].main]
                error = abs(got - value) / abs(value)
                ok = list(named) == [name] and (error <= within or (name == "sensor.range_bias" and abs(got - value) <= 0.01))
            else:
                ok = not named and name is None
            right.setdefault(f"{profile} {name or 'clear'}", []).append(ok)
            if name and not ok and changes_nothing(Path(args.recording), scenario, profile, hidden, MEASURED_SEED + k):
                unchanged.append(k)
            hidden_text = (f"{name}={value}" if isinstance(value, str) else f"{name}={value:.4g}") if name else "clear"
            named_text = ", ".join(f"{n}({format_params(p)})" for n, p in named.items()) or "nothing"
            print(f"{k:3d} {profile:13} {hidden_text:32} {'' if error is None else f'{100 * error:6.1f}%':>7} "
                  f"{result['gap_before']:8.4f} -> {result['gap_after']:.4f} {'yes' if ok else 'NO ':3} "
                  f"({time.perf_counter() - start:.0f} s) {named_text}"
                  f"{' [the draw changes nothing]' if k in unchanged else ''}", flush=True)  # fmt: skip
    print("\nper profile and effect: right / cases")
    for key, oks in right.items():
        print(f"  {key:40s} {sum(oks)}/{len(oks)}")
    total = [ok for oks in right.values() for ok in oks]
    print(f"all: {sum(total)}/{len(total)} = {100 * sum(total) / len(total):.0f} % (target {100 * spec['success']['named_exactly']:.0f} %)")
    if unchanged:
        print(f"{len(unchanged)} missed draws change no point ({', '.join(map(str, unchanged))}): no search can "
              f"name them; without them {sum(total)}/{len(total) - len(unchanged)} = "
              f"{100 * sum(total) / max(len(total) - len(unchanged), 1):.0f} %")


if __name__ == "__main__":  # the engine's workers are spawned: they import this file without running it
    main()
