"""Test-wide DDS isolation and process helpers.

Every pytest process gets its own ROS_DOMAIN_ID (inherited by the nodes it
spawns), discovery limited to localhost, and ROS logs under log/ros in the
workspace. Shared-memory transport is used when /dev/shm is usable; otherwise,
or with ``LWS_DDS_TRANSPORT=udp``, Fast DDS is restricted to UDPv4.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent


def _shm_usable(min_free_bytes: int = 64 * 2**20) -> bool:
    try:
        return os.access("/dev/shm", os.W_OK) and shutil.disk_usage("/dev/shm").free >= min_free_bytes
    except OSError:
        return False


def _domain_id() -> int:
    """1-100 from this process's id; pytest-xdist's workers (gw0, gw1, ...) of one run are told apart by the
    parity of their worker number, so two workers never share a domain even when their ids are 50 apart."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw")
    return 1 + (os.getpid() % 50) * 2 + (int(worker) if worker.isdigit() else 0) % 2


def _isolate_dds() -> None:
    os.environ["ROS_DOMAIN_ID"] = str(_domain_id())
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ.pop("ROS_STATIC_PEERS", None)
    log_dir = ROOT / "log" / "ros"
    log_dir.mkdir(parents=True, exist_ok=True)
    os.environ["ROS_LOG_DIR"] = str(log_dir)
    os.environ["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
    if os.environ.get("LWS_DDS_TRANSPORT") == "udp" or not _shm_usable():
        os.environ["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
    os.environ["PYTHONUNBUFFERED"] = "1"


_isolate_dds()


class Processes:
    """Starts child processes with the test's environment and stops them at teardown."""

    def __init__(self, tmp_path: Path) -> None:
        self._tmp = tmp_path
        self._procs: list[tuple[subprocess.Popen, Path]] = []

    def start(self, *args: str) -> subprocess.Popen:
        log = self._tmp / f"proc{len(self._procs)}.log"
        proc = subprocess.Popen(
            list(args), stdout=log.open("w"), stderr=subprocess.STDOUT, env=os.environ.copy(), start_new_session=True
        )
        self._procs.append((proc, log))
        return proc

    def output(self, proc: subprocess.Popen) -> str:
        return next(log for p, log in self._procs if p is proc).read_text()

    def stop_all(self) -> None:
        for proc, _ in self._procs:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
        for proc, _ in self._procs:
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


@pytest.fixture
def processes(tmp_path):
    procs = Processes(tmp_path)
    yield procs
    procs.stop_all()


@pytest.fixture
def cli():
    """Command prefix that runs the lidar-weather-sim CLI with this interpreter."""
    return [sys.executable, "-m", "lidar_weather_sim.cli"]


class RosHarness:
    """An rclpy context, node and executor inside the test process."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("pytest_harness", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, predicate, timeout_s: float) -> bool:
        """Spin until ``predicate()`` is true or ``timeout_s`` seconds pass; returns predicate()."""
        import time

        deadline = time.monotonic() + timeout_s
        while not predicate() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)
        return bool(predicate())

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


@pytest.fixture
def ros():
    harness = RosHarness()
    yield harness
    harness.close()


@pytest.fixture(scope="session")
def thesis_tables() -> dict:
    """The thesis' measured values (../shared/data/thesis_tables.yaml beside the workspace)."""
    import yaml

    path = Path(os.environ.get("LWS_THESIS_TABLES", ROOT.parent / "shared" / "data" / "thesis_tables.yaml"))
    return yaml.safe_load(path.read_text())


INTEGRATION_FIXTURES = {"processes", "ros", "cli"}  # child processes, DDS in the test process, the CLI


def pytest_collection_modifyitems(config, items):
    """Tests that start processes or use DDS are ``integration`` (besides any explicit marker)."""
    for item in items:
        if INTEGRATION_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.integration)
