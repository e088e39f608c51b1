"""``lidar-weather-sim``: the project's command line.

Each subcommand parses, imports what it needs lazily, calls the library and
returns an exit code; errors print one line naming the problem and exit 2.
"""

from __future__ import annotations

import argparse
import sys

from lidar_weather_sim.names import TOPIC_POINTS


def _cmd_info(args: argparse.Namespace) -> int:
    from lidar_weather_sim.bags import bag_info, format_info

    print(format_info(bag_info(args.bag)))
    return 0


def _cmd_recover(args: argparse.Namespace) -> int:
    from lidar_weather_sim.bags import recover

    report = recover(args.bag)
    print(f"recovered {report.messages_recovered} messages on {len(report.topics)} topics into {report.output}")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from lidar_weather_sim.offline import run_scenario
    from lidar_weather_sim.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    out = args.out or f"{scenario.name}_run"
    with tqdm(unit="frame", desc=scenario.name, disable=args.frames is not None and args.frames < 20) as bar:

        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        report = run_scenario(
            scenario, out, frames=args.frames, seed=args.seed, profile=args.profile, overwrite=args.overwrite,
            progress=progress,
        )  # fmt: skip
    print(f"wrote {report.frames} frames ({report.points} points, {report.simulated_s:.2f} s simulated) to {report.output}")
    return 0


def _cmd_listen(args: argparse.Namespace) -> int:
    from lidar_weather_sim.ros.cloud_listener import listen

    return listen(args.topic, args.count, args.timeout)


def _cmd_pattern(args: argparse.Namespace) -> int:
    from lidar_weather_sim.ros.pattern_node import main as pattern_main

    pattern_main(
        [
            "--ros-args",
            "-p", f"rate_hz:={float(args.rate)}",
            "-p", f"max_frames:={int(args.count)}",
            "-p", f"frame_id:={args.frame_id}",
            "-r", f"{TOPIC_POINTS}:={args.topic}",
        ]
    )  # fmt: skip
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lidar-weather-sim",
        description="Virtual automotive LiDAR in real weather: simulation, recordings and tools.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    info = commands.add_parser("info", help="topics, message counts, time span and PointCloud2 fields of a bag")
    info.add_argument("bag", metavar="BAG", help="rosbag2 directory (MCAP or sqlite3) or a .mcap file")
    info.set_defaults(func=_cmd_info)

    recover = commands.add_parser("recover", help="rebuild the index of an MCAP bag whose writer was killed")
    recover.add_argument("bag", metavar="BAG", help="rosbag2 directory or .mcap file")
    recover.set_defaults(func=_cmd_recover)

    run = commands.add_parser("run", help="simulate a scenario offline, as fast as possible, into an MCAP bag")
    run.add_argument("scenario", metavar="SCENARIO", help="name in config/scenarios or a YAML path")
    run.add_argument("--frames", type=int, help="frames to simulate (default: the scenario's duration)")
    run.add_argument("--seed", type=int, help="random seed (default: the scenario's)")
    run.add_argument("--profile", help="sensor profile overriding the scenario's (name or YAML path)")
    run.add_argument("--out", help="output rosbag2 directory (default: <scenario>_run)")
    run.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    run.set_defaults(func=_cmd_run)

    listen = commands.add_parser("listen", help="print a summary line per PointCloud2 received (like ros2 topic echo)")
    listen.add_argument("--topic", default=TOPIC_POINTS, help=f"PointCloud2 topic (default {TOPIC_POINTS})")
    listen.add_argument("--count", type=int, default=0, help="exit after this many clouds (0 = run until Ctrl-C)")
    listen.add_argument("--timeout", type=float, default=0.0, help="fail if --count clouds do not arrive in this many seconds")
    listen.set_defaults(func=_cmd_listen)

    pattern = commands.add_parser("pattern", help="publish a synthetic sweep with every point field (wiring check)")
    pattern.add_argument("--topic", default=TOPIC_POINTS, help=f"output topic (default {TOPIC_POINTS})")
    pattern.add_argument("--rate", type=float, default=10.0, help="frames per second (Hz)")
    pattern.add_argument("--count", type=int, default=0, help="stop after this many frames (0 = forever)")
    pattern.add_argument("--frame-id", default="lidar", help="header frame_id")
    pattern.set_defaults(func=_cmd_pattern)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, LookupError, OSError) as exc:
        reason = "; ".join(line for line in str(exc).splitlines() if line.strip())
        print(f"lidar-weather-sim {args.command}: error: {reason}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
