"""``weather-filter``: evaluate the weather filters on a bag and train the learned filter.

    weather-filter eval BAG [--method M] [--fallback dror|dsor] [--topic T] [--out FILE.json] [--param NAME=VALUE ...]
    weather-filter train [BAG ...] [--synthetic-frames N] [--out MODEL.joblib]

Errors print one line naming the problem and exit 2.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys

from lidar_weather_sim.names import TOPIC_POINTS

from weather_filter.filters import GEOMETRY_METHODS, METHODS


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
    from weather_filter.evaluate import evaluate_bag

    import warnings

    from weather_filter.filters import GeometryFallbackWarning

    with warnings.catch_warnings():
        warnings.simplefilter("always", GeometryFallbackWarning)
        warnings.showwarning = lambda message, *rest, **kw: print(f"weather-filter eval: warning: {message}", file=sys.stderr)
        result = evaluate_bag(args.bag, args.method, args.topic, args.fallback, **_parse_params(args.param))
    text = json.dumps(result, indent=2)
    if args.out:
        with open(args.out, "w") as stream:
            stream.write(text + "\n")
    print(text)
    return 0


def _synthetic_frames(n: int, seed: int):
    from weather_filter.synthetic import highway_frame

    weathers = ("rain", "fog", "snow", None)
    for i in range(n):
        yield highway_frame(weathers[i % 4], frame=i, seed=seed, rate=0.02 + 0.06 * ((i // 4) % 3) / 2,
                            spray=i % 2 == 0, obstacle_in_spray=i % 3 == 0)  # fmt: skip


def _cmd_train(args: argparse.Namespace) -> int:
    import itertools

    from lidar_weather_sim.bags import read_clouds

    from weather_filter.learned import DEFAULT_MODEL, train

    sources = [(frame.points for frame in read_clouds(bag, args.topic)) for bag in args.bags]
    if args.synthetic_frames:
        sources.append(_synthetic_frames(args.synthetic_frames, args.seed))
    if not sources:
        raise ValueError("nothing to train on: give labelled bags and/or --synthetic-frames N")
    frames = (p for p in itertools.chain.from_iterable(sources) if "label" in p.dtype.names)
    described = [*args.bags] + ([f"synthetic:{args.synthetic_frames}@seed{args.seed}"] if args.synthetic_frames else [])
    command = "weather-filter " + " ".join(shlex.quote(a) for a in args.argv)
    report = train(frames, args.out or DEFAULT_MODEL, trained_on=", ".join(described), command=command, seed=args.seed)
    print(
        f"trained on {report.frames} frames ({report.points} points, {report.weather_points} weather): "
        f"train precision {report.train_precision:.3f}, recall {report.train_recall:.3f}; wrote {report.output}"
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="weather-filter", description="LiDAR weather filters: evaluation and training.")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    ev = commands.add_parser("eval", help="precision/recall of removing weather points on a labelled bag (JSON)")
    ev.add_argument("bag", metavar="BAG", help="rosbag2 directory or .mcap file")
    ev.add_argument("--method", default="echo", choices=METHODS, help="filter (default echo)")
    ev.add_argument("--topic", default=TOPIC_POINTS, help=f"PointCloud2 topic (default {TOPIC_POINTS})")
    ev.add_argument("--out", help="also write the JSON to this file")
    ev.add_argument("--fallback", default="dror", choices=GEOMETRY_METHODS,
                    help="geometry-only filter for clouds lacking the method's fields (default dror)")  # fmt: skip
    ev.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="filter parameter override")
    ev.set_defaults(func=_cmd_eval)

    tr = commands.add_parser("train", help="train the learned per-point filter on labelled bags / synthetic frames")
    tr.add_argument("bags", nargs="*", metavar="BAG", help="labelled rosbag2 directories or .mcap files")
    tr.add_argument("--topic", default=TOPIC_POINTS, help=f"PointCloud2 topic (default {TOPIC_POINTS})")
    tr.add_argument("--synthetic-frames", type=int, default=0, help="add N constructed frames (weather_filter.synthetic)")
    tr.add_argument("--seed", type=int, default=0, help="random seed of sampling, synthetic frames and the MLP")
    tr.add_argument("--out", help="model file (default: the packaged models/weather_point_mlp_v<N>.joblib)")
    tr.set_defaults(func=_cmd_train)
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
