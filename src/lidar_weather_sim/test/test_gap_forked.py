"""The gap search's forked evaluation copies (``lidar_weather_sim.gap.parallel.ForkedWorkers``), without ROS."""

import os
from types import SimpleNamespace

import pytest

from lidar_weather_sim.gap.parallel import ForkedWorkers, fork_is_safe


class FakeSearch:
    """The parts of a GapSearch the copies use: a gap that is a function of its job, remembered by key with the id
    of the process that computed it, a fit, frames cast per evaluation."""

    def __init__(self) -> None:
        self.resim = SimpleNamespace(casts=0)
        self._known: dict[tuple, float] = {}
        self.computed_by: dict[tuple, int] = {}

    @property
    def known_gaps(self) -> dict[tuple, float]:
        return self._known

    def learn(self, gaps: dict[tuple, float]) -> None:
        self._known.update(gaps)

    def at_value(self, effect: str, x: float) -> str:
        return f"{effect}={x:g}"

    def gap(self, effects: list[str], split: str, redraw: int = 0) -> float:
        key = (tuple(effects), split, redraw)
        if key not in self._known:
            self.resim.casts += 10
            self._known[key] = sum(len(e) for e in effects) + 0.5 * redraw + len(split) / 100
            self._known[("pid",) + key] = float(os.getpid())
        return self._known[key]

    def fit(self, accepted: list[str], candidate: str, xs: list[float], k: int) -> tuple[str, float, int]:
        gaps = [self.gap(accepted + [self.at_value(candidate, x)], "fit") for x in xs]
        return self.at_value(candidate, xs[k]), min(gaps), len(gaps)


@pytest.mark.skipif(not fork_is_safe(), reason="this process cannot fork evaluation copies")
def test_forked_copies_give_the_gaps_and_fits_in_job_order_and_hand_back_what_they_computed():
    jobs = [([f"rain{i}"] * (i % 3 + 1), "heldout", i % 2) for i in range(7)]
    here = FakeSearch()
    expected = [here.gap(*job) for job in jobs]
    search = FakeSearch()
    workers = ForkedWorkers(2)
    workers.search = search
    values, casts = workers.gaps(jobs)
    assert values == expected
    # the parent computed the split's first job and the baseline before forking; the copies the rest
    by = {key: int(search.known_gaps[("pid",) + key]) for key in [(tuple(j[0]), j[1], j[2]) for j in jobs]}
    forked = [key for key, pid in by.items() if pid != os.getpid()]
    assert len(forked) == len(jobs) - 1 and casts == 10 * len(forked)
    assert search.resim.casts == 10 * 2  # the first job and the baseline, here
    fits = [([], "fog", [1.0, 2.0, 3.0], k) for k in range(3)]
    assert workers.fits(fits)[0] == [FakeSearch().fit(*job) for job in fits]


def test_a_batch_of_one_runs_in_this_process():
    search = FakeSearch()
    workers = ForkedWorkers(2)
    workers.search = search
    values, casts = workers.gaps([(["dirt"], "fit")])
    assert values == [FakeSearch().gap(["dirt"], "fit")] and casts == 0
    assert search.known_gaps[("pid", ("dirt",), "fit", 0)] == os.getpid()
