"""The Dask worker plugin of :mod:`lidar_weather_sim.core.engine` (imports ``distributed``)."""

from __future__ import annotations

import os

from distributed.diagnostics.plugin import WorkerPlugin


class SingleThreadedSimulator(WorkerPlugin):
    """Sets the simulator's, numba's and BLAS' thread counts (``env``: name -> value) in a worker before
    its first task, unless the worker's own environment sets them: one thread per worker process."""

    name = "lidar-weather-sim-single-threaded"

    def __init__(self, env: dict[str, str]) -> None:
        self.env = dict(env)

    def setup(self, worker) -> None:
        for key, value in self.env.items():
            os.environ.setdefault(key, value)
