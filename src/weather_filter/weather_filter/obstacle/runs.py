"""The obstacle models' training, validation and held-out runs, read from their model card
(``models/obstacle_point_hgb_v4.yaml``; why each list is what it is: ``models/obstacle_point_hgb_v4.md``), and the
run syntax ``SCENARIO:SEED:FRAMES[:PROFILE]@AUGMENT_SEED[:EPW_MATCH[:KINDS]]``: a simulated spray run
(:mod:`weather_filter.simdata` spec) and the seed of ``lidar-weather-sim augment`` (1 box per frame, the paper's
ranges)."""

from __future__ import annotations

from pathlib import Path

import yaml

#: The card the lists are read from (package data, next to the models).
RUNS_CARD = Path(__file__).resolve().parents[1] / "models" / "obstacle_point_hgb_v4.yaml"


def _read_card(path: Path = RUNS_CARD) -> dict:
    return yaml.safe_load(path.read_text())


def _run_lists(card: dict) -> dict[str, tuple[str, ...]]:
    """Each list of ``card["runs"]`` as a tuple: its own runs, or the runs of the lists it ``extends`` (in order)
    followed by its ``runs``."""
    resolved: dict[str, tuple[str, ...]] = {}

    def resolve(name: str) -> tuple[str, ...]:
        if name not in resolved:
            entry = card["runs"][name]
            if isinstance(entry, list):
                resolved[name] = tuple(entry)
            else:
                resolved[name] = sum((resolve(base) for base in entry["extends"]), ()) + tuple(entry.get("runs", ()))
        return resolved[name]

    for name in card["runs"]:
        resolve(name)
    return resolved


_CARD = _read_card()
_LISTS = _run_lists(_CARD)
#: v1 model's training runs (the paper's model).
AUGMENT_TRAIN_RUNS = _LISTS["train_runs_v1"]
#: An experiment's training runs (``train --preset augmentation-wide --out FILE``), not a shipped model's.
AUGMENT_TRAIN_RUNS_WIDE = _LISTS["train_runs_wide"]
AUGMENT_TRAIN_RUNS_V2 = _LISTS["train_runs_v2"]
AUGMENT_VALIDATION_RUNS_V2 = _LISTS["validation_runs_v2"]
AUGMENT_TRAIN_RUNS_V3 = _LISTS["train_runs_v3"]
AUGMENT_VALIDATION_RUNS_V3 = _LISTS["validation_runs_v3"]
AUGMENT_TRAIN_RUNS_V4 = _LISTS["train_runs_v4"]
AUGMENT_VALIDATION_RUNS_V4 = _LISTS["validation_runs_v4"]
#: Held-out lists 1-4, each fixed before the model it measures was trained.
AUGMENT_TEST_RUNS = _LISTS["test_runs_v1"]
AUGMENT_TEST_RUNS_V2 = _LISTS["test_runs_v2"]
AUGMENT_TEST_RUNS_V3 = _LISTS["test_runs_v3"]
AUGMENT_TEST_RUNS_V4 = _LISTS["test_runs_v4"]
#: (seed, count) of the simulator-raycast boxes (:func:`weather_filter.obstacle.data.simulated_box_bag`) of the
#: v2-v4 fits and of their validation.
SIM_BOXES_TRAIN_V2 = (int(_CARD["simulated_boxes"]["train"]["seed"]), int(_CARD["simulated_boxes"]["train"]["count"]))
SIM_BOXES_VALIDATION_V2 = (int(_CARD["simulated_boxes"]["validation"]["seed"]),
                           int(_CARD["simulated_boxes"]["validation"]["count"]))  # fmt: skip
#: Scenarios of the held-out lists never to be trained on (any training list).
HELDOUT_ONLY_SCENARIOS = tuple(_CARD["heldout_only_scenarios"])


def sim_boxes_text(seed_count: tuple[int, int]) -> str:
    seed, count = seed_count
    return f"simulated boxes 0-{count - 1} seed {seed}"


def parse_run(text: str) -> tuple[str, int]:
    """``SPEC@SEED[:EPW_MATCH[:KINDS]]`` -> (simulation spec, augmentation seed)."""
    spec, seed, _, _ = parse_run_options(text)
    return spec, seed


#: ``SPEC@SEED`` alone: the shipped v1 model's augmentation (``--epw-match none``, boxes only).
RUN_DEFAULT_EPW_MATCH = "none"
RUN_DEFAULT_KINDS = ("box",)


def parse_run_options(text: str) -> tuple[str, int, str, tuple[str, ...]]:
    """``SCENARIO:SEED:FRAMES[:PROFILE]@AUGMENT_SEED[:EPW_MATCH[:KINDS]]`` -> (simulation spec, augmentation
    seed, ``augment --epw-match`` (``none`` or ``lead``; default none), ``augment --kinds`` (default box))."""
    spec, sep, tail = text.rpartition("@")
    seed, _, options = tail.partition(":")
    epw, _, kinds = options.partition(":")
    if not sep or not spec or not seed.isdigit() or (options and epw not in ("none", "lead")):
        raise ValueError(f"augmented run {text!r}: expected SCENARIO:SEED:FRAMES[:PROFILE]@AUGMENT_SEED"
                         "[:none|lead[:KIND,...]]")  # fmt: skip
    kinds_t = tuple(k for k in kinds.split(",") if k) or RUN_DEFAULT_KINDS
    return spec, int(seed), epw or RUN_DEFAULT_EPW_MATCH, kinds_t
