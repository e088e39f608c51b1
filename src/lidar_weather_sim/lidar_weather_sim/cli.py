"""``lidar-weather-sim``: the project's command line.

Each subcommand parses, imports what it needs lazily, calls the library and
returns an exit code; errors print one line naming the problem and exit 2.
"""

from __future__ import annotations

import argparse
import os
import sys

from lidar_weather_sim.core.argtypes import (
    count_int,
    non_negative_float,
    number_in,
    port_int,
    positive_float,
    positive_int,
    seed_int,
    workers_int,
)
from lidar_weather_sim.core.names import RETURN_MODES, TOPIC_POINTS
from lidar_weather_sim.gap import FIT_FRAMES, HELDOUT_FRAMES


def _cmd_info(args: argparse.Namespace) -> int:
    from lidar_weather_sim.io.bags import bag_info, format_info

    print(format_info(bag_info(args.bag)))
    return 0


def _cmd_recover(args: argparse.Namespace) -> int:
    from lidar_weather_sim.io.bags import recover

    report = recover(args.bag)
    if report.damaged_copy is None:
        print(f"{report.output} is intact ({report.messages_recovered} messages on {len(report.topics)} topics): nothing to do")
        return 0
    print(f"recovered {report.messages_recovered} messages on {len(report.topics)} topics into {report.output} "
          f"(the damaged original is kept as {report.damaged_copy})")  # fmt: skip
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    if args.realtime:
        return _run_realtime(args)
    from tqdm import tqdm

    from lidar_weather_sim.scenario.schema import load_scenario
    from lidar_weather_sim.sim.offline import run_scenario

    scenario = load_scenario(args.scenario)
    out = args.out or f"{scenario.name}_run"
    with tqdm(unit="frame", desc=scenario.name, disable=args.frames is not None and args.frames < 20) as bar:

        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        report = run_scenario(
            scenario, out, frames=args.frames, seed=args.seed, profile=args.profile, return_mode=args.return_mode,
            overwrite=args.overwrite, progress=progress,
        )  # fmt: skip
    if report.stopped:
        print(f"lidar-weather-sim run: warning: {report.stopped}", file=sys.stderr)
    print(f"wrote {report.frames} frames ({report.points} points, {report.simulated_s:.2f} s simulated) to {report.output}")
    return 0


def _run_realtime(args: argparse.Namespace) -> int:
    """The same scenario live over DDS: lidar_sim_node in scenario mode at real time."""
    from lidar_weather_sim.ros.lidar_sim_node import main as node_main

    ros_args = ["--ros-args", "-p", f"scenario:={args.scenario}", "-p", "realtime_factor:=1.0",
                "-p", f"max_frames:={args.frames or 0}"]  # fmt: skip
    if args.seed is not None:
        ros_args += ["-p", f"seed:={args.seed}"]
    if args.profile:
        ros_args += ["-p", f"profile:={args.profile}"]
    if args.return_mode:
        ros_args += ["-p", f"return_mode:={args.return_mode}"]
    node_main(ros_args)
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


def _cmd_up(args: argparse.Namespace) -> int:
    """A graph description (config/graphs) as separate processes: what ros2 launch would start."""
    import tempfile
    from pathlib import Path

    from lidar_weather_sim.ros.graph import (
        command_line,
        load_graph,
        parameter_yaml,
        parse_assignments,
        resolve,
        resolve_steps,
        run,
    )

    graph, given = load_graph(args.graph), parse_assignments(args.arguments)
    plans, steps = resolve(graph, given), resolve_steps(graph, given)
    run_dir = Path(args.run_dir or tempfile.mkdtemp(prefix=f"lws_{args.graph}_"))
    if args.dry_run:  # the parameter files are written, so the printed commands run as they are
        run_dir.mkdir(parents=True, exist_ok=True)
        for plan in plans:
            (run_dir / f"{plan.name}.params.yaml").write_text(parameter_yaml(plan))
            print(" ".join(command_line(plan, run_dir / f"{plan.name}.params.yaml")))
        for _, cmd in steps:
            print(" ".join(cmd))
        return 0
    return run(plans, run_dir, emit=lambda line: print(line, flush=True), steps=steps)


def _node_args(pairs: list[tuple[str, object]]) -> list[str]:
    out = ["--ros-args"]
    for name, value in pairs:
        text = str(value).lower() if isinstance(value, bool) else str(value)
        out += ["-p", f"{name}:={text}"]
    return out


def _cmd_play(args: argparse.Namespace) -> int:
    if args.foxglove:
        return _play_with_foxglove(args)
    from lidar_weather_sim.ros.bag_player_node import main as player_main

    topics = f"[{', '.join(args.topics)}]" if args.topics else "['']"
    wait = f"[{', '.join(args.wait_for)}]" if args.wait_for else "['']"
    player_main(_node_args([("bag", args.bag), ("rate", float(args.rate)), ("publish_clock", not args.no_clock),
                            ("topics", topics), ("wait_for_topics", wait), ("wait_timeout_s", float(args.wait_timeout))]))  # fmt: skip
    return 0


def _play_with_foxglove(args: argparse.Namespace) -> int:
    """bag_player_node and foxglove_bridge_node as two processes (as `up` starts a graph); the player's end ends both."""
    import tempfile
    from pathlib import Path

    from lidar_weather_sim.ros.graph import NodePlan, run

    player = {"bag": str(Path(args.bag).resolve()), "rate": float(args.rate), "publish_clock": not args.no_clock,
              "wait_timeout_s": float(args.wait_timeout)}  # fmt: skip
    if args.topics:
        player["topics"] = list(args.topics)
    if args.wait_for:
        player["wait_for_topics"] = list(args.wait_for)
    bridge = {"port": int(args.foxglove_port), "host": args.foxglove_host, "use_sim_time": not args.no_clock}
    plans = [NodePlan("bag_player_node", "lidar_weather_sim", "bag_player_node", "lidar_weather_sim.ros.bag_player_node",
                      (), player, (), True),
             NodePlan("foxglove_bridge_node", "lidar_weather_sim", "foxglove_bridge_node",
                      "lidar_weather_sim.ros.foxglove_bridge_node", (), bridge, (), False)]  # fmt: skip
    return run(plans, Path(tempfile.mkdtemp(prefix="lws_play_")), emit=lambda line: print(line, flush=True))


def _cmd_record(args: argparse.Namespace) -> int:
    from lidar_weather_sim.ros.recorder_node import main as recorder_main

    recorder_main(_node_args([("out", args.out), ("topics", f"[{', '.join(args.topics)}]"), ("overwrite", args.overwrite),
                              ("max_messages", args.count), ("use_sim_time", args.use_sim_time)]))  # fmt: skip
    return 0


def _cmd_import_ouster(args: argparse.Namespace) -> int:
    from lidar_weather_sim.io.ouster_import import default_sdist, import_ouster

    mesh = args.mesh_out or f"{str(args.out).rstrip('/')}_mesh.ply"
    report = import_ouster(args.sdist or default_sdist(), args.out, mesh, overwrite=args.overwrite)
    print(f"wrote {len(report.points_per_frame)} frames ({', '.join(map(str, report.points_per_frame))} points, "
          f"{report.duration_s:.3f} s) to {report.bag}")  # fmt: skip
    print(f"wrote the street mesh ({report.triangles} triangles, map frame) to {report.mesh}")
    print("median point-to-mesh distance per frame: " + ", ".join(f"{d * 100:.1f} cm" for d in report.alignment_m))
    return 0


def _cmd_closed_loop(args: argparse.Namespace) -> int:
    from lidar_weather_sim.experiments.closed_loop import main as closed_loop_main

    return closed_loop_main(args)


def _cmd_make_measured(args: argparse.Namespace) -> int:
    from lidar_weather_sim.scenario.effects import parse_effect
    from lidar_weather_sim.references.measured import make_measured
    from lidar_weather_sim.scenario.schema import load_scenario

    effects = [parse_effect(text) for text in args.hide]
    if args.on and args.labels:
        raise ValueError("--on puts effects on a recording, which has no ground truth: --labels applies only "
                         "without --on")  # fmt: skip
    if args.beams_per_frame and args.generator != "reference":
        raise ValueError("--beams-per-frame is the reference's: it needs --reference")
    if args.intensity_scale != "profile" and not args.on:
        raise ValueError("--intensity-scale says what a recording's intensity is: it needs --on BAG")
    if args.with_actors and not args.on:
        raise ValueError("--with-actors puts the scenario's actors on a recording: it needs --on BAG")
    if args.on:
        from lidar_weather_sim.augment.command import augment_recording

        if args.frames is not None or args.seed is not None:
            raise ValueError("--on puts the effects on every frame of its recording, at the scenario's seed: "
                             "--frames and --seed apply only without --on")
        if not effects:
            raise ValueError("--on needs at least one --hide effect to put on top of the recording")

        scenario, weather, simulated = load_scenario(args.scenario), None, effects
        if args.generator != "fast":  # its weather on each merged frame, at the scenario's seed
            from lidar_weather_sim.references.measured import made_by, weather_transform

            _, weather = weather_transform(scenario, effects, args.generator, args.profile, scenario.seed,
                                           args.beams_per_frame)  # fmt: skip
            simulated = [e for e in effects if e.name not in made_by(args.generator)]
        frames = augment_recording(args.on, scenario, simulated, args.out, profile=args.profile, topic=args.topic,
                                   overwrite=args.overwrite, with_actors=args.with_actors, transform=weather,
                                   reflectivity=args.intensity_scale == "reflectivity")  # fmt: skip
        actors = " and the scenario's actors" if args.with_actors else ""
        by = "" if args.generator == "fast" else f" (weather by the {args.generator} generator)"
        print(f"wrote {frames} frames of {args.on} with {', '.join(e.label() for e in effects)}{by}{actors} on top "
              f"to {args.out}")  # fmt: skip
        return 0
    report = make_measured(load_scenario(args.scenario), effects, args.out, frames=args.frames, seed=args.seed,
                           profile=args.profile, overwrite=args.overwrite, generator=args.generator,
                           ground_truth=args.labels, beams_per_frame=args.beams_per_frame)  # fmt: skip
    hidden = ", ".join(e.label() for e in effects) or "nothing"
    hidden += "" if args.generator == "fast" else f" (weather by the {args.generator} generator)"
    lost = f", {report.dropped} dropped by the nuisance model" if report.dropped else ""
    print(f"wrote {report.frames - report.dropped} of {report.frames} frames ({report.points} points{lost}) to "
          f"{report.output} with {hidden} hidden")  # fmt: skip
    return 0


def _cmd_augment(args: argparse.Namespace) -> int:
    from lidar_weather_sim.augment.command import augment_obstacles

    done, name, kinds = augment_obstacles(args.bag, args.out, profile=args.profile, topic=args.topic,
                                          objects=args.objects, sizes_m=args.sizes, kinds=args.kinds,
                                          epw_match=args.epw_match, seed=args.seed, overwrite=args.overwrite)  # fmt: skip
    if args.epw_match == "lead" and "not matched" in done.epw:
        print(f"lidar-weather-sim augment: note: {done.epw}", file=sys.stderr)
    print(f"wrote {done.frames} frames of {args.bag} with {done.boxes} obstacles ({args.objects} per frame, "
          f"{','.join(kinds)}, profile {name}; {done.epw}) to {args.out}")  # fmt: skip
    return 0


def _sizes(text: str) -> tuple[float, float]:
    """``A:B`` (m) -> (A, B)."""
    try:
        lo, hi = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected MIN:MAX in m, e.g. 0.2:2, not {text!r}") from None
    if not 0.0 < lo <= hi:
        raise argparse.ArgumentTypeError(f"need 0 < MIN <= MAX, not {text!r}")
    return lo, hi


def _cmd_compare(args: argparse.Namespace) -> int:
    from lidar_weather_sim.gap.command import compare
    from lidar_weather_sim.scenario.schema import load_scenario

    scenario = load_scenario(args.scenario) if args.scenario else None
    m = compare(args.measured, args.simulated, args.out, scenario, args.topic)
    print(f"{m['frames']['paired']} frame pairs: gap {m['gap']:.4f}, bird's-eye Pearson {m['bev']['pearson']:.3f}; "
          f"wrote {args.out}/metrics.json, report.md and plots")  # fmt: skip
    return 0


def _cmd_gap(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from lidar_weather_sim.gap.command import run_gap

    live = sys.stderr.isatty()  # a bar on a terminal; in a log (CI, nohup, a pipe) one line per step
    with tqdm(unit="frame", desc="gap: frames cast", disable=not live) as bar:

        def progress(text: str, casts: int) -> None:
            if live:
                bar.update(casts - bar.n)
                bar.set_postfix_str(text[:60])
            else:
                print(f"gap: {casts} frames cast: {text}", file=sys.stderr, flush=True)

        result = run_gap(args.measured, args.scenario, args.out, profile=args.profile, topic=args.topic,
                         progress=progress, fit_frames=args.fit_frames, heldout_frames=args.heldout_frames,
                         scheduler=args.scheduler, workers=args.workers, families=tuple(args.effects.split(",")))  # fmt: skip
    split, bev = result["split"], result.get("heldout_bev")
    if split.get("file"):  # a twin's directory: fitted on its calibration part, scored on its held-out part
        print(f"lidar-weather-sim gap: note: used the {split['kind']} split of {split['file']} (fit on calibration, "
              f"score on held-out)", file=sys.stderr)  # fmt: skip
    pearson = f", held-out bird's-eye Pearson {bev['before']['pearson']:.3f} -> {bev['after']['pearson']:.3f}" if bev else ""
    print(f"gap {result['gap_before']:.4f} -> {result['gap_after']:.4f}: {result['found']}{pearson}; "
          f"wrote {args.out}/gap.json")  # fmt: skip
    for e in result["effects"]:
        if not e.get("named", True):
            print(f"not named: {e['name']} ({e['refused']})")
    for r in result.get("unexplained", []):
        print(f"unexplained: {r['label']}, {r['shape']} ({r['sigma']:.1f} sigma)")
    return 0


def _cmd_twin(args: argparse.Namespace) -> int:
    from pathlib import Path

    from lidar_weather_sim.twin.command import build_twin, load_input

    if Path(args.out).exists() and any(Path(args.out).iterdir()) and not args.overwrite:
        raise FileExistsError(f"{args.out} exists and is not empty (use --overwrite)")
    inp = load_input(args.bag, args.topic, args.profile, args.frames, args.split, args.sector_deg,
                     args.weather_filter)  # every check first  # fmt: skip
    r = build_twin(inp, args.out)
    print(f"lidar-weather-sim twin: weather: {r['weather_filter']['note']}")
    if r["ego_part"]["voxels"]:
        print(f"lidar-weather-sim twin: ego part: {r['ego_part']['note']} ({r['ego_part']['file']}, "
              "scenario sensor.fixed_parts)")  # fmt: skip
    if not r["deskewed"] and inp.recording.layout.has_time:  # without a time field the reader said so already
        print("lidar-weather-sim twin: note: point times are constant in some frame: KISS-ICP did not deskew",
              file=sys.stderr)  # fmt: skip
    c, d = r["coverage"], r["point_to_mesh_m"]
    print(f"twin of {r['frames']} frames ({r['split']['kind']} split, poses: {r['poses']}, profile "
          f"{r['profile']['name']} {r['profile']['how']}): {r['mesh']['triangles']} triangles; within "
          f"{r['coverage_within_m']} m of the mesh: calibration {c['calibration']:.3f}, held-out {c['heldout']:.3f} "
          f"(held-out median {d['heldout']['median']:.3f} m); {r['time_s']['total_s']:.1f} s; wrote {args.out}")  # fmt: skip
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from pathlib import Path

    from lidar_weather_sim.viz.render import render_run
    from lidar_weather_sim.viz.source import FrameSource, scenario_sizes

    sizes = None
    if args.scenario:
        from lidar_weather_sim.scenario.schema import load_scenario

        sizes = scenario_sizes(load_scenario(args.scenario))
    source = FrameSource(args.bag, args.topic, args.frames, sizes)
    report = render_run(source, args.out, color=args.color, range_m=args.range, size_px=args.size,
                        point_px=args.point_px, animation=not args.no_animation)  # fmt: skip
    for note in report.notes:
        print(f"lidar-weather-sim render: note: {note}", file=sys.stderr)
    gif = f", {report.animation.name}" if report.animation else ""
    print(f"wrote {len(report.bev)} bird's-eye and {len(report.range)} range-image pictures{gif} to {report.out} "
          f"({report.seconds_per_frame:.3f} s per frame)")  # fmt: skip
    if args.html:
        from lidar_weather_sim.viz.html import write_html

        page = write_html(FrameSource(args.bag, args.topic, args.frames, sizes), Path(args.out) / "cloud.html",
                          color=args.color, max_points=args.max_points)  # fmt: skip
        print(f"wrote {page.path} ({page.path.stat().st_size / 1e6:.1f} MB, {page.frames} frames, "
              f"at most {args.max_points} points each)")  # fmt: skip
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from lidar_weather_sim.sweep.command import run_sweep

    with tqdm(unit="run", desc="sweep") as bar:

        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        report = run_sweep(args.sweep, args.out, scheduler=args.scheduler, workers=args.workers, progress=progress)
    print(f"{report.runs} runs: {report.ran} ran ({report.failed} failed in all), {report.skipped} already done; "
          f"{report.wall_s:.1f} s; wrote {report.results} and {report.report}")  # fmt: skip
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
    run.add_argument("--frames", type=positive_int, help="frames to simulate (default: the scenario's duration)")
    run.add_argument("--seed", type=seed_int, help="random seed (default: the scenario's)")
    run.add_argument("--profile", help="sensor profile overriding the scenario's (name or YAML path)")
    run.add_argument("--return-mode", choices=RETURN_MODES, metavar="MODE",
                     help="what each beam reports of its echoes, overriding the scenario's and the profile's: "
                          "strongest, last, first, dual (last + strongest) or all (every echo)")
    run.add_argument("--out", help="output rosbag2 directory (default: <scenario>_run)")
    run.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    run.add_argument("--realtime", action="store_true",
                     help="publish live over DDS at real time instead of writing a bag (lidar_sim_node)")
    run.set_defaults(func=_cmd_run)

    listen = commands.add_parser("listen", help="print a summary line per PointCloud2 received (like ros2 topic echo)")
    listen.add_argument("--topic", default=TOPIC_POINTS, help=f"PointCloud2 topic (default {TOPIC_POINTS})")
    listen.add_argument("--count", type=count_int, default=0, help="exit after this many clouds (0 = run until Ctrl-C)")
    listen.add_argument("--timeout", type=non_negative_float, default=0.0, help="fail if --count clouds do not arrive in this many seconds")
    listen.set_defaults(func=_cmd_listen)

    pattern = commands.add_parser("pattern", help="publish a synthetic sweep with every point field (wiring check)")
    pattern.add_argument("--topic", default=TOPIC_POINTS, help=f"output topic (default {TOPIC_POINTS})")
    pattern.add_argument("--rate", type=positive_float, default=10.0, help="frames per second (Hz)")
    pattern.add_argument("--count", type=count_int, default=0, help="stop after this many frames (0 = forever)")
    pattern.add_argument("--frame-id", default="lidar", help="header frame_id")
    pattern.set_defaults(func=_cmd_pattern)

    reproduce = commands.add_parser("reproduce", help="reproduce a thesis experiment in simulation (rooftop: paper 2)")
    reproduce.add_argument("experiment", choices=["rooftop"], help="rooftop: weather statistics, Tables 2-4, Figs. 5-6")
    reproduce.add_argument("--frames", type=positive_int, default=30, help="frames per weather and sun condition")
    reproduce.add_argument("--seed", type=seed_int, default=0, help="random seed")
    reproduce.add_argument("--out", default="rooftop_reproduction", help="output directory")
    reproduce.add_argument("--tables", help="thesis_tables.yaml (default ../shared/data beside the workspace)")
    reproduce.add_argument("--profile", help="sensor profile (name in config/sensors or YAML path) instead of scala4")
    _removed(reproduce, "--fit-file", "--atmosphere-model")
    reproduce.add_argument("--states", help="the weather, street and window states per class, e.g. "
                                            "from benchmarks/calibration/fit_physical_rooftop.py --out (default "
                                            "config/rooftop_physical.yaml)")
    reproduce.set_defaults(func=lambda a: __import__("lidar_weather_sim.experiments.reproduce", fromlist=["main"]).main(a))

    measured = commands.add_parser("make-measured", help="render 'measured' data with hidden effects and nuisance")
    measured.add_argument("scenario", metavar="SCENARIO", help="name in config/scenarios or a YAML path")
    measured.add_argument("--hide", action="append", default=[], metavar="NAME:key=value[,key=value]",
                          help="effect to hide, e.g. atmosphere.fog:visual_range=60 (repeatable; see effects.py)")
    measured.add_argument("--frames", type=positive_int, help="frames (default: the scenario's duration)")
    measured.add_argument("--seed", type=seed_int, help="seed of the measurement (default: the scenario's + 1000)")
    measured.add_argument("--profile", help="sensor profile overriding the scenario's")
    measured.add_argument("--on", metavar="BAG", help="put the effects on top of this (real) recording's frames "
                                                        "instead of simulating the scenario (see augment/weather.py; "
                                                        "the weather by --generator's generator)")
    measured.add_argument("--topic", help="PointCloud2 topic of --on (default: /lidar/points or the only one)")
    measured.add_argument("--intensity-scale", choices=("profile", "reflectivity"), default="profile",
                          help="with --on: what the recording's intensity is: the profile's byte (default) or a "
                               "calibrated reflectivity in percent (Ouster's, import-ouster's), turned into the "
                               "profile's scale by its LIDAR equation at each return's range; the output holds the "
                               "profile's scale")  # fmt: skip
    measured.add_argument("--with-actors", action="store_true",
                          help="with --on: also put the scenario's actors on the recording (returns behind them "
                               "removed), e.g. the car that throws spray on a real street")  # fmt: skip
    measured.add_argument("--generator", default="fast",
                          choices=("fast", "reference", "hahner", "fog_loss", "fog_spread", "fog_shell", "precip_dsd"),
                          help="who makes fog, rain and snow: the simulator (fast, default), the independent drop-by-drop "
                               "reference (references/droplets.py), the simplified Hahner et al. 2021 fog (references/hahner.py) "
                               "or a generator fixed before use (references/generators/: fog_loss, fog_spread, fog_shell "
                               "for fog, precip_dsd for rain or snow; each with cover.dirt as its own dirty cover)")
    measured.add_argument("--reference", dest="generator", action="store_const", const="reference",
                          help="same as --generator reference")
    _removed(measured, "--atmosphere-model")
    measured.add_argument("--labels", action="store_true", help="keep label and object_id (ground truth) in the points")
    measured.add_argument("--beams-per-frame", type=positive_int,
                          help="beams the reference simulates per frame (default: all of a profile with <= 4096 beams "
                               "per frame, else 1024; the others keep their clear return, attenuated)")
    measured.add_argument("--out", required=True, help="output rosbag2 directory (MCAP)")
    measured.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    measured.set_defaults(func=_cmd_make_measured)

    augment = commands.add_parser("augment", help="insert paper 4's synthetic obstacles (boxes, cars, pedestrians, "
                                                  "tyre debris) into a recording's frames")  # fmt: skip
    augment.add_argument("bag", metavar="BAG", help="rosbag2 with a PointCloud2 topic (real or simulated)")
    augment.add_argument("--topic", help="PointCloud2 topic (default: /lidar/points or the only one)")
    augment.add_argument("--profile", help="sensor profile of the cloud (default: the shipped one that matches it)")
    augment.add_argument("--objects", type=seed_int, default=1, help="boxes per frame (default 1)")
    augment.add_argument("--sizes", type=_sizes, metavar="A:B", help="box sides in m (default: the paper's 0.2:2)")
    augment.add_argument("--kinds", default="box", metavar="K[,K...]",
                         help="obstacle kinds, drawn in equal shares: box, vehicle, pedestrian, debris (default box)")
    augment.add_argument("--epw-match", choices=("none", "lead"), default="lead",
                         help="lead (the paper, Fig. A4): inserted points' EPW mean and sd matched to the car "
                              "ahead's rear, trimmed to its range; none: the sensor model's (default lead)")  # fmt: skip
    augment.add_argument("--seed", type=seed_int, default=0, help="random seed (default 0)")
    augment.add_argument("--out", required=True, help="output rosbag2 directory (MCAP)")
    augment.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    augment.set_defaults(func=_cmd_augment)

    compare = commands.add_parser("compare", help="metrics, report and plots of a simulated vs a measured recording")
    compare.add_argument("measured", metavar="MEASURED", help="rosbag2 (MCAP or sqlite3) with a PointCloud2 topic")
    compare.add_argument("simulated", metavar="SIMULATED", help="rosbag2 (MCAP or sqlite3) with a PointCloud2 topic")
    compare.add_argument("--topic", help="PointCloud2 topic (default: /lidar/points or the only one)")
    compare.add_argument("--scenario", help="scenario whose actor sizes shape the actor zones")
    compare.add_argument("--out", default="compare_report", help="output directory")
    compare.set_defaults(func=_cmd_compare)

    gap = commands.add_parser("gap", help="re-simulate a recording, name the missing effects, fit them, report")
    gap.add_argument("measured", metavar="MEASURED", help="rosbag2 with a PointCloud2 topic and /tf (or odometry)")
    gap.add_argument("--scenario", required=True, help="scenario to re-simulate with (name or YAML path)")
    gap.add_argument("--profile", help="sensor profile overriding the scenario's")
    gap.add_argument("--topic", help="PointCloud2 topic (default: /lidar/points or the only one)")
    gap.add_argument("--fit-frames", type=positive_int, default=FIT_FRAMES, help="calibration frames used for fitting (default %(default)s)")
    gap.add_argument("--heldout-frames", type=positive_int, default=HELDOUT_FRAMES,
                     help="held-out frames used for every decision (default %(default)s)")  # fmt: skip
    gap.add_argument("--out", default="gap_report", help="output directory")
    gap.add_argument("--effects", default="weather", choices=["weather", "sensor", "weather,sensor"],
                     help="effect families to search: weather (default; the sun included), sensor (the unit's "
                          "intensity response, range bias and noise, ray drop: for real recordings) or both")  # fmt: skip
    _removed(gap, "--atmosphere-model")
    gap_engine = gap.add_mutually_exclusive_group()
    gap_engine.add_argument("--workers", type=workers_int, default=None, help="run the search's evaluations on N "
                            "forked copies of this process (default: one per CPU; 0: in this process; the result is "
                            "the same)")  # fmt: skip
    gap_engine.add_argument("--scheduler", metavar="ADDRESS", help="run them on the Dask cluster at ADDRESS (its "
                            "workers must read MEASURED at the same path)")  # fmt: skip
    gap.set_defaults(func=_cmd_gap)

    sweep = commands.add_parser("sweep", help="many seeded runs over swept scenario keys on Dask (local or a cluster), "
                                              "one metrics row per run, resumable")  # fmt: skip
    sweep.add_argument("sweep", metavar="SWEEP.yaml", help="what to run: scenario, frames, seeds, grid or random, compute")
    sweep.add_argument("--out", required=True, help="output directory (runs already in it are skipped)")
    engine = sweep.add_mutually_exclusive_group()
    engine.add_argument("--scheduler", metavar="ADDRESS", help="an existing Dask scheduler, e.g. tcp://host:8786")
    engine.add_argument("--workers", type=workers_int, default=None,
                        help="local worker processes (default: one per CPU; 0: in this process, no Dask)")  # fmt: skip
    sweep.set_defaults(func=_cmd_sweep)

    twin = commands.add_parser("twin", help="digital twin of a recording from its calibration split: mesh with "
                                            "reflectivity, split, runnable scenario, report")  # fmt: skip
    twin.add_argument("bag", metavar="BAG", help="rosbag2 with a PointCloud2 topic (poses from /tf or odometry, "
                                                 "else KISS-ICP)")  # fmt: skip
    twin.add_argument("--topic", help="PointCloud2 topic (default: /lidar/points or the only one)")
    twin.add_argument("--profile", help="sensor profile (default: the shipped one that matches the cloud, else one "
                                        "derived from it and written to DIR/profile.yaml)")  # fmt: skip
    twin.add_argument("--frames", type=positive_int, help="use the first N frames of the topic (default: all)")
    twin.add_argument("--split", choices=["auto", "frames", "sectors"], default="auto",
                      help="calibration / held-out split: even / odd frames, alternating azimuth sectors of "
                           "every frame, or auto (sectors below 4 frames; default)")  # fmt: skip
    twin.add_argument("--sector-deg", type=float, default=30.0, help="width of the alternating azimuth sectors of a "
                                                                      "sector split (deg, dividing 360; default 30)")  # fmt: skip
    twin.add_argument("--weather-filter", default="auto", metavar="NAME",
                      help="frame filter run on every frame before meshing, by its name in the entry points "
                           "lidar_weather_sim.point_filters: auto (default: 'weather', weather_filter's learned "
                           "filter, when installed, else none), none, or a registered name")  # fmt: skip
    twin.add_argument("--out", required=True, metavar="DIR", help="output directory")
    twin.add_argument("--overwrite", action="store_true", help="write into a non-empty DIR")
    twin.set_defaults(func=_cmd_twin)

    render = commands.add_parser("render", help="pictures of a bag's clouds: bird's-eye and range-image PNGs, a GIF, "
                                                "optionally a 3D HTML page (no rviz2 needed)")  # fmt: skip
    render.add_argument("bag", metavar="BAG", help="rosbag2 directory (MCAP or sqlite3) or a .mcap file")
    render.add_argument("--topic", help="PointCloud2 topic (default: /lidar/points or the only one)")
    render.add_argument("--frames", metavar="A:B", help="frames A to B-1 of the topic, counted from 0 (also A:, :B, N; "
                                                        "default: all)")  # fmt: skip
    render.add_argument("--color", choices=["label", "echo", "epw", "intensity", "distance"],
                        help="field to colour by (default: label, or distance for clouds without ground truth)")
    render.add_argument("--scenario", help="scenario whose actor sizes give the actors' boxes (the bag has none; "
                                           "without it actors are drawn as their frame's origin and heading)")  # fmt: skip
    render.add_argument("--range", type=positive_float, default=60.0,
                        help="bird's-eye window: this many m ahead, half behind, 1.5x across (default 60)")
    render.add_argument("--size", type=number_in(int, 200, 4000), default=800, help="bird's-eye side in px (200-4000)")
    render.add_argument("--point-px", type=number_in(int, 1, 8), help="dot size in px (default 3 for sparse clouds, else 2)")
    render.add_argument("--no-animation", action="store_true", help="no animation.gif")
    render.add_argument("--html", action="store_true", help="also cloud.html: the frames in 3D (orbit, zoom, frame slider, "
                                                            "colour by field), self-contained")  # fmt: skip
    render.add_argument("--max-points", type=number_in(int, 100, 500_000), default=20_000,
                        help="--html: points per frame at most (a seeded random subset; about 15 bytes each, default 20000)")
    render.add_argument("--out", required=True, metavar="DIR", help="output directory (created; files are replaced)")
    render.set_defaults(func=_cmd_render)

    up = commands.add_parser("up", help="start a graph of config/graphs as separate processes (what ros2 launch starts)")
    up.add_argument("graph", metavar="GRAPH", help="graph name in config/graphs (sim, replay_compare, closed_loop, pattern) or a path")
    up.add_argument("arguments", nargs="*", metavar="NAME:=VALUE", help="graph arguments, as for ros2 launch")
    up.add_argument("--dry-run", action="store_true", help="print the command lines and exit")
    up.add_argument("--run-dir", help="where the resolved parameter files go (default: a new temporary directory)")
    up.set_defaults(func=_cmd_up)

    play = commands.add_parser("play", help="publish a bag's topics with their original timing and /clock")
    play.add_argument("bag", metavar="BAG", help="rosbag2 directory or .mcap file")
    play.add_argument("--topics", nargs="+", help="topics to play (default: all)")
    play.add_argument("--rate", type=positive_float, default=1.0, help="playback speed factor")
    play.add_argument("--no-clock", action="store_true", help="do not publish /clock (replay the bag's own /clock)")
    play.add_argument("--wait-for", nargs="+", metavar="TOPIC", default=[],
                      help="start only once each of these topics has a subscriber, e.g. a recorder's (/clock stands "
                           "at the bag's start meanwhile)")  # fmt: skip
    play.add_argument("--wait-timeout", type=positive_float, default=30.0, help="start anyway after this many seconds")
    play.add_argument("--foxglove", action="store_true",
                      help="also run foxglove_bridge_node: watch the bag live in Foxglove at ws://127.0.0.1:8765")  # fmt: skip
    play.add_argument("--foxglove-port", type=port_int, default=8765, help="its WebSocket port (0: any free port, logged)")
    play.add_argument("--foxglove-host", default="127.0.0.1",
                      help="address it binds (default 127.0.0.1: this machine only; 0.0.0.0: every network, no authentication)")  # fmt: skip
    play.set_defaults(func=_cmd_play)

    record = commands.add_parser("record", help="record topics to an MCAP bag until Ctrl-C")
    record.add_argument("out", metavar="BAG", help="output rosbag2 directory")
    record.add_argument("--topics", nargs="+", default=[TOPIC_POINTS], help=f"topics (default {TOPIC_POINTS})")
    record.add_argument("--count", type=count_int, default=0, help="stop after this many messages (0 = until Ctrl-C)")
    record.add_argument("--overwrite", action="store_true", help="replace an existing bag")
    record.add_argument("--use-sim-time", action="store_true", help="log times from /clock")
    record.set_defaults(func=_cmd_record)

    closed = commands.add_parser("closed-loop", help="adaptive cruise demo over DDS: speed traces with/without filter, "
                                 "report; exit 1 if a variant's braking is not the expected one")
    closed.add_argument("--scenario", default="highway_spray_crosswind", help="scenario name or YAML path")
    closed.add_argument("--seconds", type=positive_float, default=6.0, help="simulated seconds per run")
    closed.add_argument("--box-at", type=non_negative_float, default=3.0, help="box variant: the box appears at this time (s)")
    closed.add_argument("--out", default="closed_loop_report", help="report directory (report.md, speed.png, traces)")
    closed.add_argument("--realtime-factor", type=positive_float, default=1.0, help="sim / wall-clock speed (at most)")
    closed.add_argument("--free-running", action="store_true", help="do not wait for the controller's answer to each "
                        "cloud (the trace then depends on the machine's speed)")
    closed.set_defaults(func=_cmd_closed_loop)

    ouster = commands.add_parser("import-ouster", help="real OS1-128 street recording (ouster-sdk sdist) as bag + mesh")
    ouster.add_argument("--sdist", help="ouster_sdk-1.0.1.tar.gz (default: .venv/cache/, from scripts/setup.sh)")
    ouster.add_argument("--out", required=True, metavar="BAG", help="output rosbag2 directory (MCAP)")
    ouster.add_argument("--mesh-out", metavar="PLY", help="street mesh for static_meshes (default: BAG_mesh.ply)")
    ouster.add_argument("--overwrite", action="store_true", help="replace an existing bag and mesh")
    ouster.set_defaults(func=_cmd_import_ouster)
    return parser


class _Removed(argparse.Action):
    """A flag of the removed fitted atmosphere model: exit 2 with one line saying so."""

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog}: error: {option_string} was removed with the fitted atmosphere model: the atmosphere "
              "is physical (drop-size distributions, Mie, the profile's optics)", file=sys.stderr)  # fmt: skip
        sys.exit(2)


def _removed(parser: argparse.ArgumentParser, *flags: str) -> None:
    """Hidden ``flags`` that exit 2 with one line (:class:`_Removed`)."""
    for flag in flags:
        parser.add_argument(flag, nargs="?", action=_Removed, help=argparse.SUPPRESS)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except BrokenPipeError:  # the reader went away (`... | head`): stop quietly, as cat does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (ValueError, LookupError, OSError) as exc:
        reason = "; ".join(line for line in str(exc).splitlines() if line.strip())
        print(f"lidar-weather-sim {args.command}: error: {reason}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
