"""The ``main()`` of every node: init, build, spin, finish; a signal at any moment ends it cleanly.

rclpy turns SIGINT/SIGTERM into a shutdown of the context. Arriving while the
node is still being built (slow imports, kernel compilation, a loaded machine),
that shutdown surfaces as an ``RCLError`` from whatever rcl call comes next
("publisher's context is invalid"); :func:`run_node` treats it, like
``KeyboardInterrupt`` and ``ExternalShutdownException``, as the requested stop:
exit status 0, ``finish`` still called.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TypeVar

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

N = TypeVar("N")


def run_node(name: str, build: Callable[[], N], spin: Callable[[N], None] | None = None, *,
             config_errors: tuple[type[BaseException], ...] = (), finish: Callable[[N], None] | None = None,
             args: list[str] | None = None) -> None:  # fmt: skip
    """Run a node: ``build()`` it, ``spin(node)`` (default :func:`rclpy.spin`) until done or stopped, ``finish(node)``.

    ``config_errors`` raised by ``build`` print ``name: reason`` on stderr and exit with status 2.
    """
    node = None
    try:
        with rclpy.init(args=args):
            try:
                node = _build(name, build, config_errors)
                (spin or rclpy.spin)(node)
            except _rclpy.RCLError:
                if rclpy.ok():
                    raise  # a real failure, not a context stopped by a signal
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None and finish is not None:
            finish(node)


def _build(name: str, build: Callable[[], N], config_errors: tuple[type[BaseException], ...]) -> N:
    try:
        return build()
    except config_errors as exc:
        print(f"{name}: {exc}", file=sys.stderr)
        sys.exit(2)
