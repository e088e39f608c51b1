"""Which gap terms an effect set wins or loses on a recording: the per-term held-out gap of each set.

The gap search (`lidar-weather-sim gap`) accepts an effect only if the sum of its terms falls; this prints the
terms themselves (zone x range / intensity / EPW, bird's-eye, channel x range, later echoes; 0 = the same as
the recording, 1 = disjoint) for nothing and for each ``--effects`` set, re-simulated on the search's held-out
frames (odd frames, as `gap` splits them), and per zone the returns per frame with their median EPW, range and
intensity. Terms below 0.01 in every column are left out; ``gap``: the weighted mean the search compares
(without the sensor family's paired terms).

    python benchmarks/validation/gap_terms.py BAG --scenario highway_clear [--profile scala4]
        --effects "atmosphere.fog:visual_range=62.5" --effects "atmosphere.fog:visual_range=1000" [--frames 10]

A set is effects joined by ``,`` in make-measured's ``--hide`` syntax (``atmosphere.fog:visual_range=200,gain=0,cover.dirt:
transmission=0.6``: a new effect starts where a name with ``:`` follows the comma).
"""

from __future__ import annotations

import argparse
import re
import sys

import numpy as np

from lidar_weather_sim.scenario.effects import parse_effect
from lidar_weather_sim.gap.split import split_frames
from lidar_weather_sim.gap.signatures import ZONES, GapResimulator, gap_terms, gap_value, measured_signature, zone_of
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.scenario.schema import load_scenario


def zone_table(name: str, frames: list[np.ndarray], contexts: list) -> list[str]:
    """Per zone: returns per frame, median EPW (m), range (m) and intensity of ``frames``."""
    rows = []
    zones = [zone_of(p, c) for p, c in zip(frames, contexts)]
    for k, zone in enumerate(ZONES):
        parts = [p[z == k] for p, z in zip(frames, zones)]
        q = np.concatenate(parts) if parts else frames[0][:0]
        if not len(q):
            rows.append(f"{name:>9} {zone:>6}: none")
            continue
        r = np.sqrt(sum(q[a].astype(np.float64) ** 2 for a in ("x", "y", "z")))
        rows.append(f"{name:>9} {zone:>6}: {len(q) / len(frames):8.1f} per frame, EPW {np.median(q['epw']):6.2f} m, "
                    f"range {np.median(r):6.2f} m, intensity {np.median(q['intensity']):5.0f}")  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag")
    ap.add_argument("--scenario", required=True)
    ap.add_argument("--profile")
    ap.add_argument("--topic")
    ap.add_argument("--effects", action="append", default=[], help="an effect set (repeatable)")
    ap.add_argument("--frames", type=int, default=10, help="held-out frames (as gap --heldout-frames)")
    args = ap.parse_args(argv)
    try:
        sets = {"nothing": []} | {text: [parse_effect(e) for e in re.split(r",(?=[\w.]+:)", text)] for text in args.effects}
        recording = Recording.load(args.bag, args.topic)
        resim = GapResimulator(recording, load_scenario(args.scenario), args.profile)
    except (ValueError, OSError) as exc:
        print(f"gap_terms: {exc}", file=sys.stderr)
        return 2
    _, held = split_frames(len(recording.frames), 1, args.frames)
    measured = measured_signature(recording, held, resim.contexts, resim.channels)
    contexts = [resim.contexts[i] for i in held]
    short = {name: "nothing" if name == "nothing" else f"set {i}" for i, name in enumerate(sets)}
    terms, gaps, tables = {}, {}, zone_table("recording", [recording.frames[i].points for i in held], contexts)
    for name, effects in sets.items():
        frames = resim.frames(effects, held)
        simulated = resim.signature(effects, held, None, frames)
        terms[name], gaps[name] = gap_terms(measured, simulated), gap_value(measured, simulated)
        tables += zone_table(short[name], frames, contexts)
    keys = [k for k in sorted(set().union(*terms.values())) if max(t.get(k, 0.0) for t in terms.values()) >= 0.01]
    print(f"held-out frames {held}")
    for name, column in short.items():
        if name != "nothing":
            print(f"{column}: {name}")
    print(f"{'term':>18} " + " ".join(f"{c:>8}" for c in short.values()))
    for key in keys:
        print(f"{key:>18} " + " ".join(f"{terms[n].get(key, 0.0):>8.3f}" for n in sets))
    print(f"{'gap':>18} " + " ".join(f"{gaps[n]:>8.4f}" for n in sets))
    print("\n".join(tables))
    return 0


if __name__ == "__main__":
    sys.exit(main())
