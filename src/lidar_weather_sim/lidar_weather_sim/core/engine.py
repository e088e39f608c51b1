"""Independent tasks in parallel on Dask distributed, or one after another in this process.

The project's many-runs jobs (``lidar-weather-sim sweep``, the weather filter's training
data, the atmosphere fit, the gap search's screening) hand their tasks to an :class:`Engine`:

- ``Engine()`` (``workers=0``, no scheduler): a plain loop in this process, the simulator on
  all its threads (``LWS_SIM_THREADS``);
- ``Engine(workers=N)``: a Dask ``LocalCluster`` of N worker processes (spawned), one
  thread each, the simulator single-threaded in them (``LWS_SIM_THREADS=1``; numba and
  OpenMP likewise), no dashboard; ``N=None``: one worker per CPU this process may use;
- ``Engine(scheduler="tcp://host:8786")``: an existing cluster. Its workers must run the
  same code and see the same files (see docs/sweep.md);
  :class:`~lidar_weather_sim.core.engine_plugin.SingleThreadedSimulator` sets the thread
  variables in each of them before its first task.

Tasks are plain picklable callables and arguments. A task that raises is reported with its
error and the others go on; a task whose worker dies is re-run on another worker by the
scheduler (``distributed.scheduler.allowed-failures`` times, then reported as failed).
Before dispatch, :meth:`Engine.warm` runs one task on one worker per host, so numba's
on-disk cache (``cache=True`` kernels) is compiled once, not raced by every worker.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

from lidar_weather_sim.core.workers import usable_cpus

SINGLE_THREAD_ENV = {"LWS_SIM_THREADS": "1", "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
                     "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}  # fmt: skip
CONNECT_TIMEOUT_S = 10.0


class EngineError(OSError):
    """The engine cannot start (unreachable scheduler, no dask installed); the message names why."""


@dataclass
class Outcome:
    """One task's end: its index in the submitted items, and its result or the error text."""

    index: int
    result: Any = None
    error: str | None = None


class Engine:
    """Context manager running tasks serially (``workers=0``), on a local cluster or on ``scheduler``."""

    def __init__(self, scheduler: str | None = None, workers: int | None = 0) -> None:
        if workers is not None and workers < 0:
            raise EngineError(f"workers must be >= 0, got {workers}")
        self.scheduler = scheduler
        self.workers = workers
        self.client = None
        self._cluster = None

    @property
    def serial(self) -> bool:
        return self.scheduler is None and self.workers == 0

    def describe(self) -> str:
        if self.serial:
            return "serial (this process)"
        if self.scheduler:
            return f"Dask cluster at {self.scheduler}"
        return f"Dask LocalCluster, {self.workers or usable_cpus()} workers x 1 thread"

    def __enter__(self) -> "Engine":
        if self.serial:
            return self
        try:
            import dask
            from distributed import Client, LocalCluster
        except ImportError as exc:  # pragma: no cover - a broken install
            raise EngineError(f"the Dask engine needs 'dask' and 'distributed' installed ({exc})") from None
        if self.scheduler:
            try:
                self.client = Client(self.scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
            except (OSError, TimeoutError, ValueError) as exc:
                raise EngineError(f"scheduler {self.scheduler}: unreachable ({type(exc).__name__}: {exc})") from None
        else:
            with dask.config.set({"distributed.worker.multiprocessing-method": "spawn",
                                  "distributed.worker.daemon": False}):  # fmt: skip
                self._cluster = LocalCluster(n_workers=self.workers or usable_cpus(), threads_per_worker=1,
                                             processes=True, dashboard_address=None, env=dict(SINGLE_THREAD_ENV),
                                             silence_logs=40)  # fmt: skip
            self.client = Client(self._cluster)
        from lidar_weather_sim.core.engine_plugin import SingleThreadedSimulator

        self.client.register_plugin(SingleThreadedSimulator(SINGLE_THREAD_ENV), name=SingleThreadedSimulator.name)
        return self

    def __exit__(self, *exc) -> None:
        if self.client is not None:
            self.client.close()
        if self._cluster is not None:
            self._cluster.close()
        self.client = self._cluster = None

    def warm(self, fn: Callable[..., Any], *args) -> None:
        """``fn(*args)`` once on one worker per host (in this process when serial), before any other task:
        compiles numba's cached kernels once per machine. Its errors are left to the real tasks to report."""
        if self.serial:
            return
        hosts: dict[str, str] = {}
        for address, info in self.client.scheduler_info()["workers"].items():
            hosts.setdefault(info.get("host", address), address)
        futures = [self.client.submit(fn, *args, workers=[a], pure=False, allow_other_workers=True)
                   for a in hosts.values()]  # fmt: skip
        for f in futures:
            f.exception()  # wait; errors surface in the real tasks

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Outcome]:
        """``fn(item)`` for every item, yielded as they finish (serial: in order)."""
        items = list(items)
        if self.serial:
            for i, item in enumerate(items):
                try:
                    yield Outcome(i, fn(item))
                except Exception as exc:  # noqa: BLE001 - reported per task, the others go on
                    yield Outcome(i, error=f"{type(exc).__name__}: {exc}")
            return
        from distributed import as_completed

        futures = self.client.map(fn, items, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        for future in as_completed(futures):
            i = index[future.key]
            if future.status == "finished":
                yield Outcome(i, future.result())
            else:
                exc = future.exception()
                yield Outcome(i, error=f"{type(exc).__name__}: {exc}")
            future.release()

