"""``weather-filter``: filter a bag, evaluate the weather filters on a bag and train the learned filter.

    weather-filter apply BAG --out BAG2 [--method M] [--fallback dror|dsor] [--topic T] [--removed TOPIC] [--overwrite]
    weather-filter eval BAG [--method M] [--fallback dror|dsor] [--topic T] [--out FILE.json] [--param NAME=VALUE ...]
    weather-filter train [BAG ...] [--sim SCENARIO:SEED:FRAMES[:PROFILE[:WEATHER]] ...] [--synthetic-frames N] [--out MODEL.joblib]
    weather-filter train-weather --sim SCENARIO:SEED:FRAMES[:PROFILE[:WEATHER]] ... [--k K] [--out MODEL.joblib]

``--preset shipped`` trains on the runs of the shipped model; a model stores its command with the
runs written out, so rerunning that command reproduces the file byte for byte.

Errors print one line naming the problem and exit 2.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys

from lidar_weather_sim.core.argtypes import number_in
from lidar_weather_sim.core.names import TOPIC_POINTS
from weather_filter.filter_methods import DEFAULT_METHOD, GEOMETRY_METHODS, METHODS, METHOD_HELP


def _parse_params(items: list[str]) -> dict:
    params = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--param {item!r}: expected NAME=VALUE")
        try:
            params[name] = json.loads(value)
        except json.JSONDecodeError:
            params[name] = value
    return params


def _cmd_eval(args: argparse.Namespace) -> int:
    from pathlib import Path

    from weather_filter.evaluate import evaluate_bag

    if args.out and not Path(args.out).resolve().parent.is_dir():  # before the evaluation, not after it
        raise ValueError(f"--out {args.out}: directory {Path(args.out).resolve().parent} does not exist")

    import warnings

    from weather_filter.points.fallback import GeometryFallbackWarning

    with warnings.catch_warnings():
        warnings.simplefilter("always", GeometryFallbackWarning)
        warnings.showwarning = lambda message, *rest, **kw: print(f"weather-filter eval: warning: {message}", file=sys.stderr)
        result = evaluate_bag(args.bag, args.method, args.topic, args.fallback, **_parse_params(args.param))
    from lidar_weather_sim.io.bags import read_clouds
    from weather_filter.obstacle.classifier import evaluate_obstacles

    obstacles = evaluate_obstacles((f.points for f in read_clouds(args.bag, args.topic)), args.obstacle_model)
    if obstacles is not None:  # the bag has label-3 points: paper 4's obstacle classifier too
        result.update(obstacles)
    text = json.dumps(result, indent=2)
    if args.out:
        with open(args.out, "w") as stream:
            stream.write(text + "\n")
    print(text)
    return 0


def _cmd_apply(args: argparse.Namespace) -> int:
    import warnings

    from weather_filter.apply import apply_bag
    from weather_filter.points.fallback import GeometryFallbackWarning

    with warnings.catch_warnings():
        warnings.simplefilter("always", GeometryFallbackWarning)
        warnings.showwarning = lambda message, *rest, **kw: print(f"weather-filter apply: warning: {message}", file=sys.stderr)
        report = apply_bag(args.bag, args.out, topic=args.topic, method=args.method, fallback=args.fallback,
                           removed_topic=args.removed, overwrite=args.overwrite)  # fmt: skip
    print(f"{args.out}: {report.summary()}")
    return 0


def _synthetic_frames(n: int, seed: int):
    from weather_filter.synthetic import highway_frame

    weathers = ("rain", "fog", "snow", None)
    for i in range(n):
        yield highway_frame(weathers[i % 4], frame=i, seed=seed, rate=0.02 + 0.06 * ((i // 4) % 3) / 2,
                            spray=i % 2 == 0, obstacle_in_spray=i % 3 == 0)  # fmt: skip


def _training_sources(args: argparse.Namespace) -> tuple[list, list[str]]:
    """Frame sequences (one per bag / simulation run / synthetic set) and their descriptions; with
    ``--single-return MODE`` each cloud as a single-return driver in that mode publishes it."""
    sources, described = _raw_training_sources(args)
    if getattr(args, "single_return", None):
        from functools import partial

        from weather_filter.points.single_return import single_return_cloud

        strip = partial(single_return_cloud, mode=args.single_return)
        sources = [map(strip, frames) for frames in sources]
        described = [f"{d} (single return: {args.single_return})" for d in described]
    return sources, described


def _raw_training_sources(args: argparse.Namespace) -> tuple[list, list[str]]:
    from weather_filter.simdata import SimSpec, frames_of

    sources, described = [], []
    specs = list(map(SimSpec.parse, args.sim))
    for spec, bag in zip(specs, _simulate_all(args, specs)):
        sources.append(frames_of(bag, args.topic))
        described.append(f"sim:{spec}")
    for bag in args.bags:
        sources.append(frames_of(bag, args.topic))
        described.append(bag)
    if args.synthetic_frames:
        sources.append(_synthetic_frames(args.synthetic_frames, args.seed))
        described.append(f"synthetic:{args.synthetic_frames}@seed{args.seed}")
    if not sources:
        raise ValueError("nothing to train on: give --sim specs, labelled bags and/or --synthetic-frames N")
    return sources, described


def _simulate_all(args: argparse.Namespace, specs: list) -> list:
    """The bags of the --sim runs, the missing ones simulated on the engine of --workers / --scheduler."""
    from weather_filter.simdata import simulate_all

    def report(spec, bag) -> None:
        print(f"simulated {spec}: {bag}", file=sys.stderr)

    try:
        return simulate_all(specs, args.cache, scheduler=args.scheduler, workers=args.workers, progress=report)
    except RuntimeError as exc:
        raise ValueError(str(exc)) from None


def _preset_specs(command: str) -> tuple[str, ...]:  # noqa: D401
    """The runs of the shipped model of ``command`` (``--preset shipped``; ``shipped-single`` trains on the same
    runs)."""
    if command == "train":
        from weather_filter.simdata import TRAIN_SPECS

        return TRAIN_SPECS
    from weather_filter.weather_class import KNN_TRAIN_SPECS

    return KNN_TRAIN_SPECS


def _stored_command(args: argparse.Namespace) -> str:
    """The command as stored in a model: every input and hyper-parameter written out (``--preset`` as its
    --sim runs, defaults explicit), without --out and --cache (where files go changes nothing)."""
    argv = [args.command, *args.bags] if args.command == "train" else [args.command]
    for spec in args.sim:
        argv += ["--sim", spec]
    if args.topic:
        argv += ["--topic", args.topic]
    if args.command == "train":
        if args.synthetic_frames:
            argv += ["--synthetic-frames", str(args.synthetic_frames)]
        if args.single_return:
            argv += ["--single-return", args.single_return]
        argv += ["--hidden", args.hidden, "--spray-weight", repr(args.spray_weight), "--solid-weight", repr(args.solid_weight)]
        if args.threshold is not None:
            argv += ["--threshold", repr(args.threshold)]
        else:
            argv += ["--object-recall", repr(args.object_recall)]
        argv += ["--seed", str(args.seed)]
    else:
        argv += ["--k", str(args.k)]
    return "weather-filter " + " ".join(shlex.quote(a) for a in argv)


def _refuse_packaged_overwrite(args: argparse.Namespace) -> None:
    """Without --out the packaged model is rewritten: allowed only to rebuild it from its own runs (``--preset
    shipped``, or its stored command with the runs written out), never from an experiment's data."""
    own_runs = tuple(args.sim) == tuple(_preset_specs(args.command))
    if args.out is None and (not own_runs or getattr(args, "bags", []) or getattr(args, "synthetic_frames", 0)):
        raise ValueError("without --out only the shipped model's own runs (--preset shipped) may rewrite the "
                         "packaged model; give --out FILE.joblib")


def _apply_preset(args: argparse.Namespace) -> None:
    if args.preset == "shipped-single":  # the single-return model: the EPW model's runs, strongest return only
        if args.single_return not in (None, "strongest"):
            raise ValueError("--preset shipped-single trains on the strongest returns: no other --single-return")
        args.single_return = "strongest"
    if args.preset:
        args.sim = [*_preset_specs(args.command), *args.sim]
    if args.command == "train-weather" and not args.sim:
        raise ValueError("nothing to train on: give --sim specs or --preset shipped")


def _cmd_train_obstacle(args: argparse.Namespace) -> int:
    """``train --preset augmentation[-v2|-v3|-v4|-wide]``: paper 4's obstacle classifier on fixed augmented runs."""
    from weather_filter.obstacle.classifier import (
        DEFAULT_OBSTACLE_MODEL,
        OBSTACLE_MODEL_V1,
        OBSTACLE_MODEL_V2,
        OBSTACLE_MODEL_V3,
    )
    from weather_filter.obstacle.data import augmented_bag, simulated_box_bag
    from weather_filter.obstacle.features import PAPER_FEATURES, V2_FEATURES, V3_FEATURES, V4_FEATURES
    from weather_filter.obstacle.runs import (
        AUGMENT_TRAIN_RUNS,
        AUGMENT_TRAIN_RUNS_V2,
        AUGMENT_TRAIN_RUNS_V3,
        AUGMENT_TRAIN_RUNS_V4,
        AUGMENT_TRAIN_RUNS_WIDE,
        AUGMENT_VALIDATION_RUNS_V2,
        AUGMENT_VALIDATION_RUNS_V3,
        AUGMENT_VALIDATION_RUNS_V4,
        SIM_BOXES_TRAIN_V2,
        SIM_BOXES_VALIDATION_V2,
        sim_boxes_text,
    )
    from weather_filter.obstacle.training import V2_HIDDEN, train_obstacle
    from weather_filter.simdata import frames_of

    if args.sim or args.bags or args.synthetic_frames:
        raise ValueError(f"--preset {args.preset} trains on its own runs (weather_filter.obstacle.runs.AUGMENT_TRAIN_RUNS*) "
                         "only: no --sim, bags or --synthetic-frames")  # fmt: skip
    # augmentation: the v1 model (threshold 0.5); augmentation-v2 / -v3: the v2 and v3 MLPs (threshold chosen on
    # validation runs taken from training scenarios); augmentation-v4: the shipped trees (threshold chosen on those
    # and on the spent held-out lists); augmentation-wide: an experiment (--out required)
    runs, validation, out, version, features = {
        "augmentation": (AUGMENT_TRAIN_RUNS, (), OBSTACLE_MODEL_V1, 1, PAPER_FEATURES),
        "augmentation-v2": (AUGMENT_TRAIN_RUNS_V2, AUGMENT_VALIDATION_RUNS_V2, OBSTACLE_MODEL_V2, 2, V2_FEATURES),
        "augmentation-v3": (AUGMENT_TRAIN_RUNS_V3, AUGMENT_VALIDATION_RUNS_V3, OBSTACLE_MODEL_V3, 3, V3_FEATURES),
        "augmentation-v4": (AUGMENT_TRAIN_RUNS_V4, AUGMENT_VALIDATION_RUNS_V4, DEFAULT_OBSTACLE_MODEL, 4, V4_FEATURES),
        "augmentation-wide": (AUGMENT_TRAIN_RUNS_WIDE, (), None, 1, PAPER_FEATURES),
    }[args.preset]
    if out is None and args.out is None:
        raise ValueError("--preset augmentation-wide is an experiment: give --out FILE.joblib")

    def sequences(run_list, boxes=None):
        sources = []
        for run in run_list:
            bag = augmented_bag(run, args.cache)
            print(f"augmented run {run}: {bag}", file=sys.stderr)
            sources.append(frames_of(bag, args.topic))
        if boxes:  # simulator-raycast boxes (v2)
            sources += [frames_of(simulated_box_bag(i, args.cache, seed=boxes[0]), args.topic) for i in range(boxes[1])]
            print(f"{sim_boxes_text(boxes)}", file=sys.stderr)
        return sources

    command = f"weather-filter train --preset {args.preset} --seed {args.seed}"
    v2 = version >= 2  # v2 to v4: simulator boxes beside the augmented runs, a validated threshold, V2_HIDDEN (MLPs)
    trained_on = ", ".join(runs) + (f", {sim_boxes_text(SIM_BOXES_TRAIN_V2)}" if v2 else "")
    report = train_obstacle(sequences(runs, SIM_BOXES_TRAIN_V2 if v2 else None), args.out or out, trained_on=trained_on,
                            command=command, seed=args.seed,
                            validation=sequences(validation, SIM_BOXES_VALIDATION_V2) if v2 else None,
                            validated_on=", ".join(validation) + f", {sim_boxes_text(SIM_BOXES_VALIDATION_V2)}" if v2 else "",
                            version=version, features=features, hidden=V2_HIDDEN if v2 else None,
                            classifier="trees" if version >= 4 else "mlp")  # fmt: skip
    s = report.scores
    val = ""
    if report.validation_scores is not None:
        v = report.validation_scores
        val = (f"; threshold {report.threshold:.2f} chosen on the validation runs (box F {v['obstacle_f1']:.4f}, "
               f"no-box F {v['no_obstacle_f1']:.4f})")  # fmt: skip
    print(f"trained the obstacle classifier on {report.frames} frames ({report.points} feature-region points, "
          f"{report.box_points} obstacle): train obstacle F1 {s['obstacle_f1']:.4f}, no-obstacle F1 "
          f"{s['no_obstacle_f1']:.4f}{val}; wrote {report.output}")  # fmt: skip
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    from weather_filter.learned.filter import DEFAULT_MODEL, SINGLE_RETURN_MODEL
    from weather_filter.learned.training import train

    if args.preset and args.preset.startswith("augmentation"):
        return _cmd_train_obstacle(args)
    _apply_preset(args)
    _refuse_packaged_overwrite(args)
    sources, described = _training_sources(args)
    hidden = tuple(int(h) for h in args.hidden.split(",") if h)
    packaged = SINGLE_RETURN_MODEL if args.single_return else DEFAULT_MODEL
    report = train(sources, args.out or packaged, trained_on=", ".join(described), command=_stored_command(args),
                   seed=args.seed, hidden=hidden, threshold=args.threshold, spray_weight=args.spray_weight,
                   solid_weight=args.solid_weight, object_recall=args.object_recall,
                   single_return=bool(args.single_return))  # fmt: skip
    print(
        f"trained on {report.frames} frames ({report.points} points, {report.weather_points} weather): threshold "
        f"{report.threshold:.2f}, train precision {report.train_precision:.4f}, recall {report.train_recall:.4f}, "
        f"object recall {report.train_object_recall:.4f}; wrote {report.output}"
    )
    return 0


def _cmd_train_weather(args: argparse.Namespace) -> int:
    from weather_filter.weather_class import DEFAULT_KNN_MODEL, train_knn

    _apply_preset(args)
    _refuse_packaged_overwrite(args)
    _simulate_all(args, args.sim)
    report = train_knn(args.sim, args.out or DEFAULT_KNN_MODEL, command=_stored_command(args), k=args.k,
                       cache_dir=args.cache, topic=args.topic)  # fmt: skip
    print(f"trained KNN (k={args.k}) on {report.frames} frames {report.per_class}; wrote {report.output}")
    return 0


def _engine_options(parser: argparse.ArgumentParser) -> None:
    """Where the --sim runs not in the cache are simulated (lidar_weather_sim.core.engine)."""
    engine = parser.add_mutually_exclusive_group()
    engine.add_argument("--workers", type=number_in(int, 0), default=0,
                        help="simulate the missing --sim runs on N local Dask worker processes (default 0: in this "
                             "process, one after another)")  # fmt: skip
    engine.add_argument("--scheduler", metavar="ADDRESS", help="simulate them on the Dask cluster at ADDRESS "
                        "(its workers must see --cache)")  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    from weather_filter.learned.training import TRAIN_OBJECT_RECALL

    parser = argparse.ArgumentParser(prog="weather-filter", description="LiDAR weather filters: offline filtering, evaluation and training.")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    ap = commands.add_parser("apply", help="filter a recording offline as weather_filter_node would; every other topic is kept")
    ap.add_argument("bag", metavar="BAG", help="rosbag2 directory or .mcap file")
    ap.add_argument("--out", required=True, metavar="BAG2", help="output rosbag2 directory (MCAP)")
    ap.add_argument("--topic", help="PointCloud2 topic to filter (default: /lidar/points, else the bag's only one)")
    ap.add_argument("--method", default=DEFAULT_METHOD, choices=METHODS, metavar="METHOD",
                    help="filter (default %(default)s, the node's): " + ", ".join(METHODS))  # fmt: skip
    ap.add_argument("--fallback", default="dror", choices=GEOMETRY_METHODS,
                    help="geometry-only filter for clouds lacking the method's fields (default dror, the node's)")  # fmt: skip
    ap.add_argument("--removed", metavar="TOPIC", help="also write the removed points on this topic")
    ap.add_argument("--overwrite", action="store_true", help="replace BAG2 if it exists")
    ap.set_defaults(func=_cmd_apply)

    ev = commands.add_parser("eval", help="precision/recall of removing weather points on a labelled bag (JSON)")
    ev.add_argument("bag", metavar="BAG", help="rosbag2 directory or .mcap file")
    ev.add_argument("--method", default=DEFAULT_METHOD, choices=METHODS, metavar="METHOD",
                    help="filter (default %(default)s): " + "; ".join(f"{m}: {METHOD_HELP[m]}" for m in METHODS))  # fmt: skip
    ev.add_argument("--topic", help=f"PointCloud2 topic (default: {TOPIC_POINTS}, else the bag's only one)")
    ev.add_argument("--out", help="also write the JSON to this file")
    ev.add_argument("--fallback", default="dror", choices=GEOMETRY_METHODS,
                    help="geometry-only filter for clouds lacking the method's fields (default dror)")  # fmt: skip
    ev.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="filter parameter override")
    ev.add_argument("--obstacle-model", metavar="PATH", help="obstacle classifier run when the bag has label-3 points "
                    "(default: the shipped models/obstacle_point_hgb_v4.joblib; earlier ones: models/obstacle_point_mlp_v1.joblib, _v2, _v3)")  # fmt: skip
    ev.set_defaults(func=_cmd_eval)

    tr = commands.add_parser("train", help="train the learned per-point filter on labelled simulation runs / bags")
    tr.add_argument("bags", nargs="*", metavar="BAG", help="labelled rosbag2 directories or .mcap files")
    tr.add_argument("--sim", action="append", default=[], metavar="SCENARIO:SEED:FRAMES[:PROFILE[:WEATHER]]",
                    help="simulate this labelled run (cached under --cache) and train on it; repeatable")  # fmt: skip
    tr.add_argument("--preset", choices=["shipped", "shipped-single", "augmentation", "augmentation-v2", "augmentation-v3", "augmentation-v4",
                                               "augmentation-wide"],
                    help="shipped: add the runs of the shipped model (simdata.TRAIN_SPECS); shipped-single: the shipped "
                         "single-return model (clouds without EPW / later echoes: the same runs, --single-return strongest; "
                         "default --out: models/weather_point_mlp_single_v<N>.joblib); augmentation-v4: train paper 4's "
                         "obstacle classifier on its augmented runs (obstacle.runs.AUGMENT_TRAIN_RUNS_V4, threshold chosen on "
                         "obstacle.runs.AUGMENT_VALIDATION_RUNS_V4; default --out: the shipped models/obstacle_point_hgb_v4.joblib); "
                         "augmentation-v3: the third model's (models/obstacle_point_mlp_v3.joblib); "
                         "augmentation-v2: the second model's (obstacle.runs.AUGMENT_TRAIN_RUNS_V2; models/obstacle_point_mlp_v2.joblib); "
                         "augmentation: the first model's runs (obstacle.runs.AUGMENT_TRAIN_RUNS, threshold 0.5; default --out: "
                         "models/obstacle_point_mlp_v1.joblib); augmentation-wide: an experiment on more runs "
                         "(obstacle.runs.AUGMENT_TRAIN_RUNS_WIDE)")  # fmt: skip
    tr.add_argument("--cache", help="directory of simulated bags (default .venv/cache/weather_filter)")
    tr.add_argument("--topic", help=f"PointCloud2 topic (default: {TOPIC_POINTS}, else the bag's only one)")
    tr.add_argument("--synthetic-frames", type=number_in(int, 0), default=0, help="add N constructed frames (weather_filter.synthetic)")
    tr.add_argument("--hidden", default="16", help="hidden layer sizes, comma-separated (default 16; paper 4: 10)")
    tr.add_argument("--spray-weight", type=number_in(float, 0, open_low=True), default=20.0, help="weight of spray points in the fit (default 20)")
    tr.add_argument("--solid-weight", type=number_in(float, 0, open_low=True), default=3.0, help="weight of solid points in the fit (default 3)")
    tr.add_argument("--threshold", type=number_in(float, 0, 1, open_low=True, open_high=True), help="weather probability threshold (default: chosen on the training "
                    "points for the best F1 at >= --object-recall)")
    tr.add_argument("--object-recall", type=number_in(float, 0, 1, open_low=True), default=TRAIN_OBJECT_RECALL,
                    help=f"least share of the training solid points the chosen threshold keeps (default {TRAIN_OBJECT_RECALL})")  # fmt: skip
    tr.add_argument("--seed", type=number_in(int, 0), default=0, help="random seed of sampling, synthetic frames and the MLP")
    tr.add_argument("--single-return", choices=["strongest", "first", "last"],
                    help="train the single-return model: every training cloud as a single-return driver in this mode "
                         "publishes it (one point per beam, no EPW / echo fields; weather_filter.points.single_return)")  # fmt: skip
    tr.add_argument("--out", help="model file (default: the packaged models/weather_point_mlp_v<N>.joblib, with "
                    "--single-return models/weather_point_mlp_single_v<N>.joblib)")
    _engine_options(tr)
    tr.set_defaults(func=_cmd_train)

    tw = commands.add_parser("train-weather", help="train the per-frame weather classifier (KNN) on simulation runs")
    tw.add_argument("--sim", action="append", default=[], metavar="SCENARIO:SEED:FRAMES[:PROFILE[:WEATHER]]",
                    help="simulate this run; its weather class comes from the scenario's weather block; repeatable")  # fmt: skip
    tw.add_argument("--preset", choices=["shipped"], help="add the runs of the shipped model (weather_class.KNN_TRAIN_SPECS)")
    tw.add_argument("--cache", help="directory of simulated bags (default .venv/cache/weather_filter)")
    tw.add_argument("--topic", help=f"PointCloud2 topic (default: {TOPIC_POINTS}, else the bag's only one)")
    tw.add_argument("--k", type=number_in(int, 1), default=5, help="neighbours (default 5)")
    tw.add_argument("--out", help="model file (default: the packaged models/weather_knn_v<N>.joblib)")
    _engine_options(tw)
    tw.set_defaults(func=_cmd_train_weather)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    args.argv = argv
    try:
        return args.func(args)
    except (ValueError, LookupError, OSError) as exc:
        reason = "; ".join(line for line in str(exc).splitlines() if line.strip())
        print(f"weather-filter {args.command}: error: {reason}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
