"""``lidar-weather-sim sweep`` end to end: serial and on a real Dask cluster (scheduler and two
worker processes, one killed mid-sweep), resumable, failures recorded, bad input refused."""

from __future__ import annotations

import csv
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

DASK = str(Path(sys.executable).parent / "dask")


def _sweep(tmp_path: Path, name: str = "sweep.yaml", **keys) -> Path:
    spec = {"scenario": "highway_spray", "frames": 2, "profile": "scala4", "seeds": [1, 2],
            "grid": {"weather.fog.visual_range_m": [50, 300]}, "compute": ["stats"], **keys}
    path = tmp_path / name
    path.write_text(yaml.safe_dump(spec))
    return path


def _rows(out: Path) -> list[dict[str, str]]:
    with open(out / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def _without_time(rows, also=()):
    return [{k: v for k, v in r.items() if k != "elapsed_s" and k not in also} for r in rows]


def _run(cli, *args, env=None, timeout=600):
    return subprocess.run([*cli, "sweep", *map(str, args)], capture_output=True, text=True, timeout=timeout,
                          env=env or os.environ.copy())


def test_serial_sweep_rows_resume_and_a_failing_run(cli, tmp_path):
    metrics = tmp_path / "my_metrics.py"
    metrics.write_text("def far_points(bag, run):\n"
                       "    if run.seed == 2 and run.point['weather.fog.visual_range_m'] == 300:\n"
                       "        raise RuntimeError('this run is broken on purpose')\n"
                       "    from lidar_weather_sim.io.bags import read_clouds\n"
                       "    import numpy as np\n"
                       "    return {'beyond_30m': float(np.mean([(np.hypot(f.points['x'], f.points['y']) > 30).sum()\n"
                       "                                         for f in read_clouds(bag)]))}\n")
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    sweep = _sweep(tmp_path, compute=["stats", "my_metrics:far_points"])
    out = tmp_path / "out"
    result = _run(cli, sweep, "--out", out, "--workers", 0, env=env)
    assert result.returncode == 0, result.stderr
    rows = _rows(out)
    assert [(r["seed"], r["weather.fog.visual_range_m"]) for r in rows] == [("1", "50"), ("2", "50"), ("1", "300"), ("2", "300")]
    assert [r["status"] for r in rows] == ["ok", "ok", "ok", "error"]
    assert "this run is broken on purpose" in rows[3]["error"]
    ok = rows[:3]
    assert all(float(r["frames"]) == 2 and float(r["points_per_frame_mean"]) > 100 for r in ok)
    # dense fog (50 m) hides the far scene that light fog (300 m) shows
    assert float(rows[0]["far_points_beyond_30m"]) < float(rows[2]["far_points_beyond_30m"])
    assert all((out / "runs" / r["run_id"] / "metadata.yaml").exists() for r in rows)
    assert (out / "report.md").exists() and list((out / "plots").glob("*.png"))
    # resume: the three good runs are skipped, the failed one runs again (and fails again)
    again = _run(cli, sweep, "--out", out, "--workers", 0, env=env)
    assert again.returncode == 0, again.stderr
    assert "1 ran (1 failed in all), 3 already done" in again.stdout
    assert _without_time(_rows(out))[:3] == _without_time(rows)[:3]


@pytest.mark.parametrize("keys, args, reason", [
    ({"grid": {"weather.fog.visibility": [60]}}, [], "weather.fog.visibility"),
    ({"grid": {}}, [], "'grid' is empty"),
    ({"frame": 3}, [], "frame"),
    pytest.param({}, ["--scheduler", "tcp://127.0.0.1:{port}"], "unreachable", marks=pytest.mark.slow),  # ~12 s
])
def test_bad_input_one_line_exit_2_nothing_written(cli, tmp_path, keys, args, reason):
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "out"
    result = _run(cli, _sweep(tmp_path, **keys), "--out", out, *(a.format(port=port) for a in args), timeout=120)
    assert result.returncode == 2
    errors = [line for line in result.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and reason in errors[0], result.stderr
    assert not out.exists()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


WORKER_STATE = """
import sys
def worker_state(bag, run):
    from lidar_weather_sim.core import workers
    return {"sim_threads": workers.THREADS, "rclpy_loaded": "rclpy" in sys.modules}
"""


@pytest.mark.slow
def test_cluster_by_address_survives_a_killed_worker_and_matches_serial(cli, tmp_path, processes, monkeypatch):
    (tmp_path / "probe.py").write_text(WORKER_STATE)
    monkeypatch.setenv("PYTHONPATH", f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    sweep = _sweep(tmp_path, seeds=[1, 2, 3], grid={"weather.fog.visual_range_m": [40, 100, 400]}, frames=3,
                   compute=["stats", "probe:worker_state"])
    serial = tmp_path / "serial"
    assert _run(cli, sweep, "--out", serial, "--workers", 0).returncode == 0
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    processes.start(DASK, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--dashboard-address", ":0")
    workers = [processes.start(DASK, "worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard",
                               "--name", f"w{k}") for k in range(2)]  # fmt: skip
    out = tmp_path / "cluster"
    sweep_proc = subprocess.Popen([*cli, "sweep", str(sweep), "--out", str(out), "--scheduler", address],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and sweep_proc.poll() is None:  # kill a worker once the first run has landed
        rows = out / "rows.jsonl"
        if rows.exists() and rows.read_text().count("\n") >= 1:
            break
        time.sleep(0.2)
    assert sweep_proc.poll() is None, "the sweep ended before a worker could be killed"
    os.killpg(workers[0].pid, signal.SIGKILL)
    stdout, stderr = sweep_proc.communicate(timeout=600)
    assert sweep_proc.returncode == 0, stderr
    assert workers[0].wait(timeout=10) is not None and workers[1].poll() is None
    cluster_rows = _rows(out)
    assert len(cluster_rows) == 9 and all(r["status"] == "ok" for r in cluster_rows), stdout
    # the workers run the simulator single-threaded and never load rclpy
    assert {(r["worker_state_sim_threads"], r["worker_state_rclpy_loaded"]) for r in cluster_rows} == {("1.0", "0.0")}
    state = ("worker_state_sim_threads",)  # the serial loop runs on all of this process' threads
    assert _without_time(cluster_rows, state) == _without_time(_rows(serial), state)
