"""Graph descriptions (config/graphs): the launch files and `lidar-weather-sim up` read the same one; `up` over DDS.

The launch-file check runs each launch/*.launch.py against a minimal stand-in of
``launch``/``launch_ros`` (not installable here) that records the actions, and
compares the nodes it would start with what ``up`` starts for the same arguments.
"""

from __future__ import annotations

import importlib.util
import os
import re
import signal
import sys
import types
from pathlib import Path

import pytest

from lidar_weather_sim.ros.graph import available_graphs, command_line, load_graph, resolve, resolve_steps

ROOT = Path(__file__).resolve().parents[1]
LAUNCH_FILES = sorted((ROOT / "launch").glob("*.launch.py"))
REQUIRED_ARGS = {"replay_compare": {"bag": "/tmp/bag", "out": "/tmp/out"}}


class _Recorder:
    def __init__(self, kind: str):
        self.kind = kind

    def __call__(self, *args, **kwargs):
        return types.SimpleNamespace(kind=self.kind, args=args, kwargs=kwargs)


@pytest.fixture
def fake_launch(monkeypatch):
    launch = types.ModuleType("launch")
    launch.LaunchDescription = lambda entities: list(entities)
    actions = types.ModuleType("launch.actions")
    for name in ("DeclareLaunchArgument", "OpaqueFunction", "Shutdown", "RegisterEventHandler", "EmitEvent", "ExecuteProcess"):
        setattr(actions, name, _Recorder(name))
    handlers, events, process = (types.ModuleType(f"launch.{m}") for m in ("event_handlers", "events", "events.process"))
    handlers.OnProcessExit, process.SignalProcess = _Recorder("OnProcessExit"), _Recorder("SignalProcess")
    events.matches_action = lambda action: ("matches", action)
    launch_ros = types.ModuleType("launch_ros")
    ros_actions = types.ModuleType("launch_ros.actions")
    ros_actions.Node = _Recorder("Node")
    modules = {"launch": launch, "launch.actions": actions, "launch.event_handlers": handlers, "launch.events": events,
               "launch.events.process": process, "launch_ros": launch_ros, "launch_ros.actions": ros_actions}  # fmt: skip
    for name, mod in modules.items():
        monkeypatch.setitem(sys.modules, name, mod)


def _run_launch_file(path: Path, given: dict[str, str]):
    spec = importlib.util.spec_from_file_location(path.stem.replace(".", "_"), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    entities = module.generate_launch_description()
    declared = {e.args[0]: e.kwargs["default_value"] for e in entities if e.kind == "DeclareLaunchArgument"}
    context = types.SimpleNamespace(launch_configurations={**declared, **given})
    (opaque,) = [e for e in entities if e.kind == "OpaqueFunction"]
    return module.GRAPH, declared, opaque.kwargs["function"](context)


def test_every_graph_has_a_launch_file_and_every_launch_file_a_graph(fake_launch):
    graphs = {_run_launch_file(p, REQUIRED_ARGS.get(p.name.split(".")[0], {}))[0] for p in LAUNCH_FILES}
    assert graphs == set(available_graphs()) == {"sim", "replay_compare", "closed_loop", "pattern"}


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
@pytest.mark.parametrize("variant", ["defaults", "options"])
def test_launch_file_starts_what_up_starts(fake_launch, path, variant):
    options = {"filter": "true", "regions": "[cover, atmosphere]", "scenario": "highway_spray", "rate_hz": "20",
               "foxglove": "true", "foxglove_port": "9000"}  # fmt: skip
    graph_name = path.name.split(".")[0]
    graph = load_graph(graph_name)
    given = {**REQUIRED_ARGS.get(graph_name, {})}
    if variant == "options":
        given.update({k: v for k, v in options.items() if k in graph.arguments})
    name, declared, entities = _run_launch_file(path, given)
    assert name == graph_name
    assert declared == {n: a.default for n, a in graph.arguments.items()}
    plans, steps = resolve(graph, given), resolve_steps(graph, given)
    nodes = [e for e in entities if e.kind == "Node"]
    assert [n.kwargs["name"] for n in nodes] == [p.name for p in plans]
    for node, plan in zip(nodes, plans):
        kw = node.kwargs
        assert (kw["package"], kw["executable"]) == (plan.package, plan.executable)
        assert kw["parameters"] == [*(str(f) for f in plan.parameter_files), plan.parameters]
        assert kw["remappings"] == list(plan.remappings)
        assert ("on_exit" in kw) == (plan.required and not steps)
        cmd = command_line(plan, Path("/tmp/p.yaml"))
        assert cmd[cmd.index("-m") + 1] == plan.module
        assert all(str(f) in cmd for f in plan.parameter_files)
    _check_after_steps(entities, nodes, plans, steps)


def _exit(code: int):
    """(event, context) of launch's OnProcessExit handler for a process that exited with ``code``."""
    return types.SimpleNamespace(returncode=code), types.SimpleNamespace(is_shutdown=False)


def _check_after_steps(entities, nodes, plans, steps):
    """The launch handlers do what `up` does: the first required node's exit SIGINTs the rest, once; when all
    exited cleanly, the steps run in turn (then launch ends: nothing runs); a failed step raises (status 1)."""
    handlers = [e.args[0].kwargs for e in entities if e.kind == "RegisterEventHandler"]
    if not steps:
        assert handlers == []
        return
    on_exit = {id(h["target_action"]): h["on_exit"] for h in handlers}
    first = next(n for n, p in zip(nodes, plans) if p.required)
    others = [n for n in nodes if n is not first]
    signals = on_exit[id(first)](*_exit(0))  # a required node exits first
    assert [e.kwargs["event"].kwargs["process_matcher"] for e in signals] == [("matches", n) for n in others]
    assert all(e.kwargs["event"].kwargs["signal_number"] == signal.SIGINT for e in signals)
    results = [on_exit[id(n)](*_exit(-signal.SIGINT)) for n in others]  # then the others, stopped by that signal
    assert results[:-1] == [None] * (len(others) - 1)  # no second SIGINT from another required node
    (start,) = results[-1]  # the last one to exit starts the first step
    chain = [start]
    while following := on_exit[id(chain[-1])](*_exit(0)):
        chain += following
    assert [(e.kind, e.kwargs["name"], e.kwargs["cmd"]) for e in chain] == [("ExecuteProcess", *step) for step in steps]
    with pytest.raises(RuntimeError, match=f"{steps[-1][0]} failed \\(status 1\\)"):
        on_exit[id(chain[-1])](*_exit(1))


def test_failed_node_stops_the_graph_before_its_steps(fake_launch):
    """replay_compare under launch: a node that fails (here the bag cannot be read) stops the graph, the steps
    are not run and launch exits with status 1 (the handler raises), as `up` returns 1."""
    path = ROOT / "launch" / "replay_compare.launch.py"
    _, _, entities = _run_launch_file(path, REQUIRED_ARGS["replay_compare"])
    on_exit = {id(h["target_action"]): h["on_exit"] for h in (e.args[0].kwargs for e in entities if e.kind == "RegisterEventHandler")}
    recorder, lidar, player = [e for e in entities if e.kind == "Node"]
    assert len(on_exit[id(player)](*_exit(1))) == 2  # SIGINT to recorder_node and lidar_sim_node
    assert on_exit[id(lidar)](*_exit(-signal.SIGINT)) is None
    with pytest.raises(RuntimeError, match=r"^bag_player_node \(status 1\) failed; not running compare$"):
        on_exit[id(recorder)](*_exit(-signal.SIGINT))


def test_resolve_types_conditions_and_errors():
    from lidar_weather_sim.core.config import ConfigError

    sim = load_graph("sim")
    (node,) = resolve(sim, {"realtime_factor": "2", "max_frames": "7", "regions": "[cover]", "use_sim_time": "true"})
    assert node.parameters["realtime_factor"] == 2.0 and isinstance(node.parameters["realtime_factor"], float)
    assert node.parameters["max_frames"] == 7 and node.parameters["regions"] == ["cover"]
    assert node.parameters["use_sim_time"] is True and "profile" not in node.parameters  # empty: node default
    assert [p.name for p in resolve(sim, {"filter": "true"})] == ["lidar_sim_node", "weather_filter_node"]
    *_, bridge = resolve(sim, {"foxglove": "true", "use_sim_time": "true"})
    assert bridge.name == "foxglove_bridge_node" and bridge.module == "lidar_weather_sim.ros.foxglove_bridge_node"
    assert bridge.parameters == {"host": "127.0.0.1", "port": 8765, "scenario": "highway_clear", "use_sim_time": True}
    for graph in ("closed_loop", "pattern"):  # the graphs that offer the live view
        assert resolve(load_graph(graph), {"foxglove": "true"})[-1].name == "foxglove_bridge_node"
        assert "foxglove_bridge_node" not in [p.name for p in resolve(load_graph(graph))]
    loop = {p.name: p for p in resolve(load_graph("closed_loop"), {"filter": "false"})}
    assert list(loop) == ["lidar_sim_node", "ego_controller_node"] and loop["ego_controller_node"].parameters["cloud_topic"] == "/lidar/points"
    # $(graph nodes): the clock waits for every other node the graph starts; none: the parameter is left out
    assert loop["lidar_sim_node"].parameters["wait_for_ready"] == ["ego_controller_node"]
    assert loop["lidar_sim_node"].parameters["synchronous"] is True
    assert loop["lidar_sim_node"].parameters["sync_topics"] == ["/ego/cmd_speed"]
    filtered = resolve(load_graph("closed_loop"), {"filter": "true", "synchronous": "false"})[0].parameters
    assert filtered["wait_for_ready"] == ["weather_filter_node", "ego_controller_node"] and filtered["synchronous"] is False
    assert "wait_for_ready" not in node.parameters
    for bad, match in (({"nope": "1"}, "has no argument nope"), ({"pose_source": "gps"}, "not one of"),
                       ({"max_frames": "1.5"}, "is not a int"), ({"filter": "maybe"}, "not one of"),
                       ({"regions": "[]"}, "cannot hold an empty list")):  # fmt: skip
        with pytest.raises(ConfigError, match=match):
            resolve(sim, bad)
    with pytest.raises(ConfigError, match="unknown graph 'simm'"):
        load_graph("simm")
    with pytest.raises(ConfigError, match=r"graph 'replay_compare' requires out:=\.\.\.$"):
        resolve(load_graph("replay_compare"), {"bag": "/tmp/bag"})


def _logged_stamp_ns(pattern: str, log: str) -> int | None:
    """The ``SEC.NANOSEC s`` stamp after ``pattern`` in a node's log line (None if not logged yet)."""
    m = re.search(re.escape(pattern) + r" (\d+)\.(\d{9}) s", log)
    return None if m is None else int(m.group(1)) * 1_000_000_000 + int(m.group(2))


def test_up_runs_the_sim_graph_clouds_at_the_profile_rate_and_a_region_swap_at_the_next_frame(processes, cli, ros, tmp_path):
    """scenario mode: /clock at 100 Hz of sim time, scala4 clouds every 40 ms; rain appears from the next frame to start.

    "Next" is relative to the node's simulated time when the set arrives, which the test cannot see (its /clock
    lags): the node logs that time and the stamp of the first frame cast with the new regions; the test checks
    both against its own clock and the clouds.
    """
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import PointCloud2

    from lidar_weather_sim.ros.conversions import msg_to_cloud, stamp_to_ns

    up = processes.start(*cli, "up", "sim", "scenario:=highway_spray", "regions:=[spray]", "filter:=true",
                         "--run-dir", str(tmp_path / "run"))  # fmt: skip
    clouds, filtered, clocks = [], [], []
    queued = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)  # a busy test process queues, drops nothing
    ros.node.create_subscription(PointCloud2, "/lidar/points", clouds.append, queued)
    ros.node.create_subscription(PointCloud2, "/lidar/points/filtered", filtered.append, queued)
    ros.node.create_subscription(Clock, "/clock", lambda m: clocks.append(stamp_to_ns(m.clock)),
                                 QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))  # fmt: skip
    assert ros.spin_until(lambda: len(clouds) >= 15, timeout_s=180), processes.output(up)
    client = AsyncParameterClient(ros.node, "lidar_sim_node")
    assert client.wait_for_services(timeout_sec=60)
    requested_ns = clocks[-1]  # the node's simulated time when the set arrives is this or later
    future = client.set_parameters([Parameter("regions", value=["atmosphere", "spray"])])
    assert ros.spin_until(future.done, timeout_s=120) and future.result().results[0].successful
    swap = lambda: _logged_stamp_ns("in use from the frame stamped", processes.output(up))  # noqa: E731
    assert ros.spin_until(lambda: swap() is not None, timeout_s=180), processes.output(up)
    set_ns = _logged_stamp_ns("regions=['atmosphere', 'spray']: requested at", processes.output(up))
    swap_ns = swap()
    # the next frame to start: scala4 fires its first column at the scan start, so that is the first frame
    # starting after the set, or at the set itself when the set came before that first column
    assert requested_ns <= set_ns <= swap_ns <= set_ns + 40_000_000, (requested_ns, set_ns, swap_ns)
    assert ros.spin_until(lambda: stamp_to_ns(clouds[-1].header.stamp) >= swap_ns + 10 * 40_000_000, timeout_s=180)
    decoded = [(stamp_to_ns(m.header.stamp), msg_to_cloud(m).points) for m in clouds]
    stamps = [s for s, _ in decoded]
    assert all(b - a == 40_000_000 for a, b in zip(stamps, stamps[1:]) if b - a < 80_000_000)  # 25 Hz on sim time
    assert sum(b - a == 40_000_000 for a, b in zip(stamps, stamps[1:])) >= len(stamps) - 3  # best effort: few lost
    ticks = sorted(set(clocks))
    assert all(b - a == 10_000_000 for a, b in zip(ticks, ticks[1:])) or len(ticks) < 2  # 100 Hz poses
    assert decoded[0][1].dtype.names == ("x", "y", "z", "intensity", "return_type", "channel", "azimuth", "elevation",
                                         "distance", "time_stamp", "echo", "label", "epw", "object_id")  # fmt: skip
    rain = [(s, int((p["label"] == 11).sum())) for s, p in decoded]
    assert all(n == 0 for s, n in rain if s < swap_ns), rain  # every frame before the swap: spray only
    after = [n for s, n in rain if s >= swap_ns]
    assert len(after) >= 8 and all(n > 0 for n in after) and sum(after) >= 3 * len(after), rain  # the swap frame on: rain
    assert filtered, "weather_filter_node (filter:=true) published nothing"
    up.send_signal(signal.SIGINT)
    assert up.wait(timeout=60) == 0, processes.output(up)
    out = processes.output(up)
    assert "[up] lidar_sim_node exited with status 0" in out and "[up] weather_filter_node exited with status 0" in out


def test_up_fails_when_a_node_fails(processes, cli, tmp_path):
    """lidar_sim_node is required: its failure stops the filter too, and up exits 1."""
    up = processes.start(*cli, "up", "sim", "scenario:=no_such_scenario", "filter:=true", "--run-dir", str(tmp_path / "run"))
    assert up.wait(timeout=60) == 1, processes.output(up)
    out = processes.output(up)
    assert "lidar_sim_node exited with status 2 (failure)" in out
    # stopped by up: at once (0) or, still in its warm-up on a loaded machine, by the SIGTERM after the grace time
    assert re.search(r"weather_filter_node exited with status (0|-15)\b", out), out



STUCK_NODE = """
import signal, time
import rclpy
from lidar_weather_sim.ros.node_main import run_node

def stuck_where_no_python_handler_runs(node):
    for sig in (signal.SIGINT, signal.SIGTERM):  # as inside a C call that never returns: no handler runs
        signal.signal(sig, signal.SIG_IGN)
    print("stuck", flush=True)
    while True:
        time.sleep(0.05)

run_node("stuck_node", lambda: rclpy.create_node("stuck_node"), stuck_where_no_python_handler_runs)
"""


@pytest.mark.slow
def test_up_prints_the_stacks_of_a_node_deaf_to_sigint_and_sigterm_before_killing_it(tmp_path, monkeypatch):
    """A node stuck where no Python signal handler runs still answers SIGUSR1 with its threads' stacks (node_main)."""
    from lidar_weather_sim.ros.graph import NodePlan, run

    (tmp_path / "stuck_node.py").write_text(STUCK_NODE)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    plan = NodePlan("stuck_node", "test", "stuck_node", "stuck_node", (), {}, (), True)
    lines: list[str] = []

    def emit(line: str) -> None:
        lines.append(line)
        if line == "[stuck_node] stuck":  # stop the graph as Ctrl-C would
            os.kill(os.getpid(), signal.SIGINT)

    assert run([plan], tmp_path / "run", emit=emit, grace_s=1.0) == 1
    out = "\n".join(lines)
    assert "[up] still running after SIGTERM: stuck_node; their threads' Python stacks follow, then SIGKILL" in out
    assert "in stuck_where_no_python_handler_runs" in out, out  # faulthandler's dump from inside the stuck spin
    assert f"[up] stuck_node exited with status {-signal.SIGKILL} (failure)" in out


HUNG_TEARDOWN_NODE = """
import signal, time
import rclpy.node
from lidar_weather_sim.ros.node_main import run_node

class HungTeardownNode(rclpy.node.Node):
    def destroy_node(self):  # as Fast DDS deadlocked in a C call that holds the GIL: no handler runs
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)
        while True:
            time.sleep(0.05)

run_node("hung_node", lambda: HungTeardownNode("hung_node"), lambda node: None,
         finish=lambda node: print("work done", flush=True))
"""


@pytest.mark.slow
def test_a_node_whose_middleware_teardown_hangs_after_its_work_ends_within_the_teardown_limit(tmp_path, monkeypatch):
    """node_main bounds the teardown after ``finish``: stacks at TEARDOWN_S, SIGALRM a second later; up counts
    the node as done (its work finished) and says why, instead of waiting for its grace time and SIGKILL."""
    from lidar_weather_sim.ros.graph import TEARDOWN_CUT, NodePlan, run

    (tmp_path / "hung_node.py").write_text(HUNG_TEARDOWN_NODE)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    plan = NodePlan("hung_node", "test", "hung_node", "hung_node", (), {}, (), True)
    lines: list[str] = []
    assert run([plan], tmp_path / "run", emit=lines.append, grace_s=30.0) == 0, "\n".join(lines)
    out = "\n".join(lines)
    assert "[hung_node] work done" in out
    assert "in destroy_node" in out, out  # faulthandler's dump from inside the hung teardown
    assert f"[up] hung_node exited with status {TEARDOWN_CUT} (its work done; the middleware's teardown hung" in out
    assert "still running after SIGTERM" not in out
