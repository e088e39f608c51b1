"""Node graphs described once (``config/graphs/*.yaml``), started by ``ros2 launch`` or by ``lidar-weather-sim up``.

A graph description lists launch arguments and nodes (package, executable,
Python module, parameter files, parameters, remappings, conditions). The same
description feeds two front ends:

- :func:`launch_description` builds a ``launch`` LaunchDescription (full ROS 2
  install: ``ros2 launch lidar_weather_sim sim.launch.py scenario:=...``);
- :func:`resolve` + :func:`command_line` give the separate processes that
  ``lidar-weather-sim up GRAPH name:=value ...`` starts here (no ``launch``).

Substitution: a parameter value or remapping target written ``$(arg NAME)`` is
replaced by the argument's value, parsed as a YAML scalar or list as
``ros2 launch`` does (``true`` -> bool, ``0.5`` -> float, ``[a, b]`` -> list); a
parameter whose argument is empty is left out (the node's default applies).
A parameter value written ``$(graph nodes)`` becomes the names of every other node the
graph starts (the clock's ``wait_for_ready``: :mod:`lidar_weather_sim.ros.readiness`); left out
when there is none.
Conditions: ``if: NAME`` starts the node only when the argument is true,
``unless: NAME`` only when it is false. ``required: true``: when that node
exits, the whole graph shuts down (launch's ``on_exit=Shutdown()``).
An argument without ``default`` is required (``ros2 launch`` and ``up`` refuse
to start without it).
``after:`` steps (commands, e.g. ``lidar-weather-sim compare`` on what the
graph recorded) run one after the other once every node has exited cleanly;
their arguments may contain ``$(arg NAME)`` anywhere. Under ``ros2 launch`` the
first required node's exit then stops the other nodes with one SIGINT instead
of a shutdown, the first step starts when the last node has exited, and
launch ends when the last step has (nothing is left running); a failed node or
step makes ``ros2 launch`` exit with status 1, as ``up`` does.

No ROS import at module level: ``launch`` is imported only by :func:`launch_description`.
"""

from __future__ import annotations

import re
import signal
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import Field

from lidar_weather_sim.core.config import ConfigError, ConfigModel, load_yaml
from lidar_weather_sim.core.paths import config_dir

_ARG = re.compile(r"^\$\(arg ([A-Za-z_][A-Za-z0-9_]*)\)$")
_ARG_ANYWHERE = re.compile(r"\$\(arg ([A-Za-z_][A-Za-z0-9_]*)\)")
TRUE, FALSE = ("true", "1", "yes", "on"), ("false", "0", "no", "off", "")
GRAPH_NODES = "$(graph nodes)"


class Argument(ConfigModel):
    default: str | None = Field(None, description="Default value (a string, as on the ros2 launch command line); none: required")
    description: str = Field("", description="Shown by ros2 launch --show-args and lidar-weather-sim up --help")
    choices: list[str] | None = Field(None, description="Allowed values (None: any)")
    type: Literal["auto", "str", "int", "float", "bool", "list"] = Field(
        "auto", description="Parameter type of $(arg ...) values (auto: as YAML reads the text)"
    )


class GraphNode(ConfigModel):
    name: str = Field(description="Node name (also the prefix of its output lines)")
    package: str = Field(description="ROS package (ros2 launch / ros2 run)")
    executable: str = Field(description="Console script in the package (ros2 launch / ros2 run)")
    module: str = Field(description="Python module with main(args): how `lidar-weather-sim up` runs it")
    parameter_files: list[str] = Field(default_factory=list, description="ROS 2 parameter YAML, relative to config/graphs")
    parameters: dict[str, Any] = Field(default_factory=dict, description="Parameters; values may be $(arg NAME)")
    remappings: dict[str, str] = Field(default_factory=dict, description="from topic -> to topic ($(arg NAME) allowed)")
    if_: str | None = Field(None, alias="if", description="Start only when this argument is true")
    unless: str | None = Field(None, description="Start only when this argument is false")
    required: bool = Field(False, description="Its exit shuts the graph down")


class GraphStep(ConfigModel):
    name: str = Field(description="Step name (also the prefix of its output lines)")
    module: str = Field(description="Python module run with -m")
    args: list[str] = Field(default_factory=list, description="Arguments; $(arg NAME) is substituted anywhere")


class Graph(ConfigModel):
    name: str
    description: str = ""
    arguments: dict[str, Argument] = Field(default_factory=dict)
    nodes: list[GraphNode] = Field(min_length=1)
    after: list[GraphStep] = Field(default_factory=list, description="Commands run once every node has exited")


@dataclass(frozen=True)
class NodePlan:
    """One node to start, with every argument substituted."""

    name: str
    package: str
    executable: str
    module: str
    parameter_files: tuple[Path, ...]
    parameters: dict[str, Any]
    remappings: tuple[tuple[str, str], ...]
    required: bool


def graphs_dir() -> Path:
    return config_dir() / "graphs"


def available_graphs() -> list[str]:
    return sorted(p.stem for p in graphs_dir().glob("*.yaml"))


def load_graph(name_or_path: str | Path) -> Graph:
    """A graph by name (config/graphs/NAME.yaml) or path; checks references to arguments and parameter files."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = graphs_dir() / f"{name_or_path}.yaml"
        if not path.exists():
            raise ConfigError(f"unknown graph '{name_or_path}'; available: {', '.join(available_graphs())}")
    graph = load_yaml(path, Graph)
    for node in graph.nodes:
        used = [node.if_, node.unless, *_arg_refs(node.parameters.values()), *_arg_refs(node.remappings.values())]
        for ref in filter(None, used):
            if ref not in graph.arguments:
                raise ConfigError(f"{path}: node '{node.name}' uses undeclared argument '{ref}'")
        for file in node.parameter_files:
            if not (path.parent / file).is_file():
                raise ConfigError(f"{path}: node '{node.name}': parameter file {file} not found")
    for step in graph.after:
        for ref in (m.group(1) for a in step.args for m in _ARG_ANYWHERE.finditer(a)):
            if ref not in graph.arguments:
                raise ConfigError(f"{path}: step '{step.name}' uses undeclared argument '{ref}'")
    return graph


def _arg_refs(values) -> list[str]:
    return [m.group(1) for v in values if isinstance(v, str) and (m := _ARG.match(v))]


def parse_assignments(items: list[str]) -> dict[str, str]:
    """``name:=value`` command-line arguments (ros2 launch syntax) as a mapping."""
    out = {}
    for item in items:
        name, sep, value = item.partition(":=")
        if not sep or not name:
            raise ConfigError(f"argument {item!r} is not of the form name:=value")
        out[name] = value
    return out


def argument_values(graph: Graph, given: dict[str, str]) -> dict[str, str]:
    """Every argument's value: given or default; unknown names and values outside ``choices`` are errors."""
    unknown = sorted(set(given) - set(graph.arguments))
    if unknown:
        raise ConfigError(f"graph '{graph.name}' has no argument {', '.join(unknown)}; it takes {', '.join(graph.arguments)}")
    missing = [name for name, arg in graph.arguments.items() if arg.default is None and name not in given]
    if missing:
        raise ConfigError(f"graph '{graph.name}' requires {', '.join(f'{name}:=...' for name in missing)}")
    values = {name: given.get(name, arg.default) for name, arg in graph.arguments.items()}
    for name, arg in graph.arguments.items():
        if arg.choices is not None and values[name] not in arg.choices:
            raise ConfigError(f"argument {name}:={values[name]!r} is not one of {', '.join(arg.choices)}")
    return values


def _truth(name: str, value: str) -> bool:
    if value.strip().lower() in TRUE:
        return True
    if value.strip().lower() in FALSE:
        return False
    raise ConfigError(f"argument {name}:={value!r} must be true or false")


def _typed(name: str, text: str, kind: str) -> Any:
    """A launch argument's text as a parameter value of type ``kind`` (auto: as YAML reads it, like ros2 launch)."""
    if kind == "str":
        return text
    if kind == "bool":
        return _truth(name, text)
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        value = None
    if kind == "auto":
        return text if value is None or isinstance(value, dict) else value
    ok = {"int": isinstance(value, int) and not isinstance(value, bool),
          "float": isinstance(value, (int, float)) and not isinstance(value, bool),
          "list": isinstance(value, list)}[kind]  # fmt: skip
    if not ok:
        raise ConfigError(f"argument {name}:={text!r} is not a {kind}")
    if value == []:
        raise ConfigError(f"argument {name}:=[]: a ROS parameter file cannot hold an empty list; leave it empty for the node's default")
    return float(value) if kind == "float" else value


def resolve(graph: Graph, given: dict[str, str] | None = None) -> list[NodePlan]:
    """The nodes to start for these argument values, in description order."""
    values = argument_values(graph, given or {})
    started = [node for node in graph.nodes if not (node.if_ and not _truth(node.if_, values[node.if_]))
               and not (node.unless and _truth(node.unless, values[node.unless]))]  # fmt: skip
    plans = []
    for node in started:
        params = {}
        for key, value in node.parameters.items():
            m = _ARG.match(value) if isinstance(value, str) else None
            if value == GRAPH_NODES:
                others = [other.name for other in started if other.name != node.name]
                if others:
                    params[key] = others
            elif m is None:
                params[key] = value
            elif values[m.group(1)].strip():
                arg = m.group(1)
                params[key] = _typed(arg, values[arg], graph.arguments[arg].type)
        remaps = tuple((src, values[m.group(1)] if (m := _ARG.match(dst)) else dst) for src, dst in node.remappings.items())
        files = tuple((graphs_dir() / f).resolve() for f in node.parameter_files)
        plans.append(NodePlan(node.name, node.package, node.executable, node.module, files, params, remaps, node.required))
    return plans


def resolve_steps(graph: Graph, given: dict[str, str] | None = None) -> list[tuple[str, list[str]]]:
    """(name, command line) of each ``after`` step for these argument values."""
    values = argument_values(graph, given or {})
    sub = lambda text: _ARG_ANYWHERE.sub(lambda m: values[m.group(1)], text)  # noqa: E731
    return [(step.name, [sys.executable, "-m", step.module, *map(sub, step.args)]) for step in graph.after]


def parameter_yaml(plan: NodePlan) -> str:
    """The plan's inline parameters as a ROS 2 parameter file (wildcard node name)."""
    return yaml.safe_dump({"/**": {"ros__parameters": plan.parameters}}, sort_keys=False)


def command_line(plan: NodePlan, params_file: Path) -> list[str]:
    """The process ``lidar-weather-sim up`` starts for ``plan`` (``params_file``: where parameter_yaml was written)."""
    args = [sys.executable, "-m", plan.module, "--ros-args", "-r", f"__node:={plan.name}"]
    for file in (*plan.parameter_files, params_file):
        args += ["--params-file", str(file)]
    for src, dst in plan.remappings:
        args += ["-r", f"{src}:={dst}"]
    return args


def launch_description(name: str):
    """A ``launch.LaunchDescription`` of graph ``name``: its arguments declared, its nodes from :func:`resolve`."""
    from launch.actions import DeclareLaunchArgument, OpaqueFunction, Shutdown
    from launch_ros.actions import Node

    from launch import LaunchDescription

    graph = load_graph(name)

    def nodes(context):
        given = {k: v for k, v in context.launch_configurations.items() if k in graph.arguments}
        plans, steps = resolve(graph, given), resolve_steps(graph, given)
        actions = []
        for plan in plans:
            extra = {"on_exit": Shutdown()} if plan.required and not steps else {}
            actions.append(Node(
                package=plan.package, executable=plan.executable, name=plan.name, output="screen",
                parameters=[*(str(f) for f in plan.parameter_files), plan.parameters],
                remappings=list(plan.remappings), **extra,
            ))  # fmt: skip
        return actions + (_after_steps(plans, actions, steps) if steps else [])

    declared = [
        DeclareLaunchArgument(n, default_value=a.default, description=a.description, **({"choices": a.choices} if a.choices else {}))
        for n, a in graph.arguments.items()
    ]
    return LaunchDescription([*declared, OpaqueFunction(function=nodes)])


def _after_steps(plans: list[NodePlan], nodes: list, steps: list[tuple[str, list[str]]]) -> list:
    """launch event handlers doing what :func:`run` does for a graph with ``after`` steps.

    The first required node to exit sends SIGINT once to the nodes still running
    (a second SIGINT would stop a node at once, e.g. a recorder closing its bag).
    When every node has exited cleanly (:func:`_exited_cleanly`), the steps run
    in turn; launch ends once the last one has exited, as nothing runs any more
    (a launch_testing test marked ``keep_alive`` can still check the outputs). A
    failed node or step raises: launch shuts down, reports the message and
    ``ros2 launch`` exits with status 1. Once launch is shutting down (e.g.
    Ctrl-C), nothing more starts.
    """
    from launch.actions import EmitEvent, ExecuteProcess, RegisterEventHandler
    from launch.event_handlers import OnProcessExit
    from launch.events import matches_action
    from launch.events.process import SignalProcess

    processes = [ExecuteProcess(cmd=cmd, name=step, output="screen") for step, cmd in steps]
    codes: dict[int, int] = {}  # id(node action) -> exit status
    signalled: set[int] = set()  # id(node action) of the nodes sent SIGINT

    def node_exit(plan: NodePlan, action):
        def handler(event, context):
            codes[id(action)] = event.returncode
            if context.is_shutdown:
                return None
            running = [other for other in nodes if id(other) not in codes]
            if running:
                if not plan.required or signalled:
                    return None
                signalled.update(map(id, running))
                return [EmitEvent(event=SignalProcess(signal_number=signal.SIGINT, process_matcher=matches_action(other)))
                        for other in running]  # fmt: skip
            failed = [f"{p.name} (status {codes[id(n)]})" for p, n in zip(plans, nodes)
                      if not _exited_cleanly(codes[id(n)], id(n) in signalled)]  # fmt: skip
            if failed:
                raise RuntimeError(f"{', '.join(failed)} failed; not running {', '.join(name for name, _ in steps)}")
            return [processes[0]]

        return RegisterEventHandler(OnProcessExit(target_action=action, on_exit=handler))

    def step_exit(name: str, following):
        def handler(event, context):
            if context.is_shutdown:
                return None
            if event.returncode != 0:
                raise RuntimeError(f"{name} failed (status {event.returncode})")
            return [following] if following else None

        return handler

    handlers = [node_exit(plan, action) for plan, action in zip(plans, nodes)]
    for (name, _), current, following in zip(steps, processes, [*processes[1:], None]):
        handlers.append(RegisterEventHandler(OnProcessExit(target_action=current, on_exit=step_exit(name, following))))
    return handlers


TEARDOWN_CUT = -signal.SIGALRM  # a node whose work was done and whose middleware teardown hung (node_main)


def _exited_cleanly(code: int, signalled: bool) -> bool:
    """Status 0, a teardown cut short after the node's work (:data:`TEARDOWN_CUT`), or (for a node the graph
    sent SIGINT) the status of that SIGINT."""
    return code in (0, TEARDOWN_CUT) or (signalled and code in (-signal.SIGINT, 128 + signal.SIGINT))


def _exit_note(code: int, clean: bool) -> str:
    if code == TEARDOWN_CUT:
        return " (its work done; the middleware's teardown hung and was cut short: its stacks are above)"
    return "" if clean else " (failure)"


# --- running a graph as separate processes (lidar-weather-sim up) ---------------------------------


def run(plans: list[NodePlan], run_dir: Path, emit=print, grace_s: float = 10.0,
        steps: list[tuple[str, list[str]]] = ()) -> int:  # fmt: skip
    """Start every plan as its own process, prefix their output lines, stop them all cleanly, then run ``steps``.

    SIGINT and SIGTERM received here are forwarded as SIGINT to every node (the
    ``ros2 launch`` behaviour); a node still running ``grace_s`` later gets
    SIGTERM, then SIGUSR1 (it prints its threads' stacks: :mod:`.node_main`), then
    SIGKILL. The graph stops when a ``required`` node exits or when every node has
    exited. Then, unless interrupted or a node failed, the ``after`` steps
    (:func:`resolve_steps`) run one after the other. Returns 0 if every node exited
    cleanly (status 0, or stopped by the forwarded signal) and every step with
    status 0, otherwise 1.
    """
    import os
    import subprocess
    import threading
    import time

    run_dir.mkdir(parents=True, exist_ok=True)
    received: list[int] = []
    previous = {s: signal.signal(s, lambda signum, _: received.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)}
    procs: list[tuple[NodePlan, subprocess.Popen]] = []
    pumps: list[threading.Thread] = []

    def pump(name: str, stream) -> None:
        for line in stream:
            emit(f"[{name}] {line.rstrip()}")

    try:
        for plan in plans:
            params = run_dir / f"{plan.name}.params.yaml"
            params.write_text(parameter_yaml(plan))
            proc = subprocess.Popen(command_line(plan, params), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    text=True, bufsize=1, start_new_session=True)  # fmt: skip
            pumps.append(threading.Thread(target=pump, args=(plan.name, proc.stdout), daemon=True))
            pumps[-1].start()
            procs.append((plan, proc))
            emit(f"[up] started {plan.name} (pid {proc.pid})")
        while not received:
            if any(p.required and proc.poll() is not None for p, proc in procs):
                break
            if all(proc.poll() is not None for _, proc in procs):
                break
            time.sleep(0.05)
        stopped = {proc.pid for _, proc in procs if proc.poll() is None}
        for sig, wait_s in ((signal.SIGINT, grace_s), (signal.SIGTERM, 5.0), (signal.SIGUSR1, 1.0),
                            (signal.SIGKILL, 5.0)):  # fmt: skip
            alive = [proc for _, proc in procs if proc.poll() is None]
            if sig == signal.SIGUSR1 and alive:  # node_main.STACKS_SIGNAL: a node prints its stacks
                emit(f"[up] still running after SIGTERM: {', '.join(p.name for p, proc in procs if proc in alive)};"
                     " their threads' Python stacks follow, then SIGKILL")  # fmt: skip
            for proc in alive:
                try:
                    os.killpg(proc.pid, sig)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + wait_s
            while any(proc.poll() is None for proc in alive) and time.monotonic() < deadline:
                time.sleep(0.05)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    for thread in pumps:
        thread.join(timeout=2.0)
    clean = True
    for plan, proc in procs:
        code = proc.wait()
        ok = _exited_cleanly(code, proc.pid in stopped)
        clean &= ok
        emit(f"[up] {plan.name} exited with status {code}{_exit_note(code, ok)}")
    for name, cmd in steps if clean and not received else ():
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
        emit(f"[up] started {name} (pid {proc.pid})")
        pump(name, proc.stdout)
        code = proc.wait()
        clean &= code == 0
        emit(f"[up] {name} exited with status {code}{'' if code == 0 else ' (failure)'}")
        if code:
            break
    return 0 if clean else 1
