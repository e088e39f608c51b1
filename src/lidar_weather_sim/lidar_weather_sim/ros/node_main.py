"""The ``main()`` of every node: init, build, spin, finish; SIGINT/SIGTERM at any moment end it cleanly.

rclpy's own signal handler lives below Python's ``signal`` module: anything
that later installs a Python handler replaces it without a trace, a signal
during start-up surfaces as an ``RCLError`` from the next rcl call, and a
signal that lands while the executor is being set up can be lost (seen: a
weather_filter_node and a recorder_node still spinning minutes after SIGINT).
So rclpy is initialised without signal handlers and :func:`run_node`
installs plain Python ones. The first SIGINT only records the request: every
spin loop waits at most :data:`POLL_S` and checks :func:`stop_requested`, so
an idle node stops within that time, a busy one after its callback. SIGTERM,
or a second SIGINT, raises ``KeyboardInterrupt`` at once, wherever the node
is (a long numba compilation of a cold cache in its first cast can take 10 s
or more on a loaded machine): the escalation of ``ros2 launch`` and
``lidar-weather-sim up`` (SIGINT, then SIGTERM after a grace period) ends
even a busy node. ``finish`` always runs (the recorder closes its bag there), before the middleware
is torn down; then the node is destroyed and the context shut down within :data:`TEARDOWN_S`. Fast DDS can
deadlock while it destroys a node's endpoints (seen once in ``make demo``: ego_controller_node stuck in
``destroy_node``; eProsima/Fast-DDS#6193 is one such deadlock), and rclpy's destroy calls hold the GIL, so no
Python thread can help: faulthandler's own thread prints every stack after :data:`TEARDOWN_S` and the kernel
ends the process with SIGALRM a second later, a status (-14) that ``lidar-weather-sim up`` reports as a cut
teardown of a node whose work was done. A node stuck in C code (where no Python signal handler can run) still
answers SIGUSR1: it prints every thread's Python stack on stderr (``faulthandler``), which ``lidar-weather-sim up``
asks for before its SIGKILL. Every node starts with the Fast DDS profile for dense clouds
(:mod:`lidar_weather_sim.ros.dds_profile`) and, once built, says it is ready on ``/<node>/ready``
(:mod:`lidar_weather_sim.ros.readiness`).
"""

from __future__ import annotations

import faulthandler
import signal
import sys
from collections.abc import Callable
from typing import TypeVar

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.signals import SignalHandlerOptions

from lidar_weather_sim.ros.dds_profile import use_large_message_profile
from lidar_weather_sim.ros.readiness import announce_ready

N = TypeVar("N")
POLL_S = 0.1  # longest wait in a spin loop (s): the reaction time to a signal
TEARDOWN_S = 5  # the longest the middleware's teardown may take once the node's work is done (s)
STACKS_SIGNAL = signal.SIGUSR1  # prints every thread's Python stack on stderr, even from inside C code
_requested: list[int] = []


def stop_requested() -> bool:
    """True once SIGINT or SIGTERM arrived (with :func:`run_node`'s handlers) or the rclpy context is down."""
    return bool(_requested) or not rclpy.ok()


def spin_until_stopped(node) -> None:
    """The default spin: callbacks until a stop is requested."""
    while not stop_requested():
        rclpy.spin_once(node, timeout_sec=POLL_S)


def run_node(name: str, build: Callable[[], N], spin: Callable[[N], None] = spin_until_stopped, *,
             config_errors: tuple[type[BaseException], ...] = (), finish: Callable[[N], None] | None = None,
             args: list[str] | None = None) -> None:  # fmt: skip
    """Run a node: ``build()`` it, ``spin(node)`` until done or stopped, then ``finish(node)``.

    ``spin`` must return soon after :func:`stop_requested` turns true. ``config_errors``
    raised by ``build`` print ``name: reason`` on stderr and exit with status 2. ``finish`` does the node's
    own closing (files, bags); the node is destroyed here, after it.
    """
    use_large_message_profile()
    faulthandler.register(STACKS_SIGNAL, all_threads=True)
    try:
        with rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO):
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, _on_signal)
            node = _build(name, build, config_errors)
            announce_ready(node)  # the constructor did the warm-up: /<node>/ready (latched)
            try:
                if not stop_requested():
                    spin(node)
            finally:
                try:
                    if finish is not None:
                        finish(node)  # before the middleware is torn down
                finally:
                    _bound_teardown()
                    node.destroy_node()
    except (KeyboardInterrupt, ExternalShutdownException):  # escalated, or before the handlers were in place
        pass
    finally:
        signal.alarm(0)  # torn down in time
        faulthandler.cancel_dump_traceback_later()


def _bound_teardown() -> None:
    """From now on, at most :data:`TEARDOWN_S` until the process ends (a C-level limit: the GIL may be held)."""
    faulthandler.dump_traceback_later(TEARDOWN_S, exit=False)
    signal.signal(signal.SIGALRM, signal.SIG_DFL)
    signal.alarm(TEARDOWN_S + 1)


def _on_signal(signum: int, _frame) -> None:
    if signum == signal.SIGTERM or _requested:
        raise KeyboardInterrupt  # escalation: stop now, wherever the node is
    _requested.append(signum)


def _build(name: str, build: Callable[[], N], config_errors: tuple[type[BaseException], ...]) -> N:
    """``build()``; a configuration error, or a parameter value rclpy refuses at declaration (out of its
    range, wrong type: ``-p max_frames:=-5``), prints one line and exits with status 2."""
    try:
        return build()
    except (*config_errors, ParameterException) as exc:
        reason = " ".join(str(exc).split())  # rclpy's messages span lines
        print(f"{name}: {reason}", file=sys.stderr)
        sys.exit(2)
