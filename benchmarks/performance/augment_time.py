#!/usr/bin/env python3
"""Time per frame of paper 4's augmentation and of its classifier (thesis line 2810: features and inference
182 +- 51 ms per frame in single-threaded C++).

Simulates ``--frames`` frames of SCENARIO (default highway_spray) once, then times, per frame:
``augment`` (``ObstacleAugmenter.frame``: drawing the boxes, raycasting them with the profile's scan pattern,
occlusion and noise; ``--objects`` per frame) and the obstacle classifier (features of the feature region and
the classifier: MLP or trees). Prints median and mean ms per frame (wall clock, this machine; the first frame, with JIT warm-up, is
left out).

Usage: python benchmarks/performance/augment_time.py [--scenario highway_spray] [--profile P] [--frames 20] [--objects 1]
       [--model PATH (default: the shipped obstacle model)]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from lidar_weather_sim.augment.obstacles import ObstacleAugmenter
from lidar_weather_sim.replay import road_level
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.sim.offline import run_scenario
from weather_filter.obstacle.classifier import ObstacleClassifier


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="highway_spray")
    ap.add_argument("--profile", help="sensor profile overriding the scenario's")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--objects", type=int, default=1)
    ap.add_argument("--model", help="obstacle model (default: the shipped one)")
    args = ap.parse_args()
    scenario = load_scenario(args.scenario)
    name = args.profile or scenario.sensor.profile
    profile = load_profile(name)
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "bag"
        run_scenario(scenario, bag, frames=args.frames + 1, seed=1, profile=args.profile)
        recording = Recording.load(bag)
    augmenter = ObstacleAugmenter(profile, args.objects, seed=1)
    classifier = ObstacleClassifier.load(args.model)
    road_z = road_level(recording)
    t_aug, t_cls, points = [], [], []
    for frame in recording.frames:
        t0 = time.perf_counter()
        out, _ = augmenter.frame(frame.points, recording.scan_index(frame, profile.period_s), road_z)
        t1 = time.perf_counter()
        classifier.predict(out)
        t2 = time.perf_counter()
        t_aug.append(t1 - t0), t_cls.append(t2 - t1), points.append(len(out))
    t_aug, t_cls = np.array(t_aug[1:]) * 1e3, np.array(t_cls[1:]) * 1e3
    print(f"{args.scenario}, profile {name}, {len(t_aug)} frames, {np.mean(points):.0f} points per frame, "
          f"{args.objects} box(es) per frame; obstacle model version {classifier.bundle.get('version')}, "
          f"{len(classifier.bundle['feature_names'])} features, {classifier.bundle.get('classifier', 'mlp')}, hidden {classifier.bundle['hidden']}")
    print(f"augment:               median {np.median(t_aug):.1f} ms/frame, mean {t_aug.mean():.1f} +- {t_aug.std():.1f}")
    print(f"features + inference:  median {np.median(t_cls):.1f} ms/frame, mean {t_cls.mean():.1f} +- {t_cls.std():.1f} "
          "(paper 4, C++: 182 +- 51)")


if __name__ == "__main__":
    main()
