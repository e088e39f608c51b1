"""The gap search's fits on the calibration frames: one candidate's value, and the accepted effects together.

:meth:`EffectFitter.fit` refines a candidate between the grid neighbours of its best screened value by bounded
Brent minimisation (scipy); :meth:`EffectFitter.refit` fits the accepted effects again together (coordinate
descent, and from the best point of a pairwise grid when that screens better).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from lidar_weather_sim.gap.acceptance import AcceptanceRule
from lidar_weather_sim.scenario.effects import Effect, search_grid


class EffectFitter(AcceptanceRule):
    """The evaluations with the fits of the module doc."""

    def _objective(self, accepted: list[Effect], candidate: Effect, split: str, cache: dict[float, float]):
        """The gap of ``accepted`` + ``candidate`` at search-space value x, memoised in ``cache``."""

        def objective(x: float) -> float:
            key = round(float(x), 6)
            if key not in cache:
                cache[key] = self.gap(accepted + [self.at_value(candidate, x)], split)
            return cache[key]

        return objective

    def fit(self, accepted: list[Effect], candidate: Effect, xs: np.ndarray, k: int,
            cache: dict[float, float] | None = None) -> tuple[Effect, float, int]:  # fmt: skip
        """Brent refinement on the calibration frames between the grid neighbours of ``xs[k]``
        (``cache``: calibration gaps already known, by search-space value); a categorical effect is
        tried with every choice instead. Returns the effect at its best value, its gap and the evaluations."""
        spec = candidate.spec
        cache = {} if cache is None else cache
        objective = self._objective(accepted, candidate, "fit", cache)
        if spec.categorical:
            for x in search_grid(spec, len(spec.choices)):
                objective(x)
            x = min(cache, key=cache.get)
            return self.at_value(candidate, x), cache[x], len(cache)
        objective(xs[k])
        lo, hi = xs[max(k - 1, 0)], xs[min(k + 1, len(xs) - 1)]
        tol = 0.01 if spec.log_search else 0.002 * (spec.bounds[1] - spec.bounds[0])
        minimize_scalar(objective, bounds=(lo, hi), method="bounded", options={"xatol": tol, "maxiter": 10})
        x = min(cache, key=cache.get)
        return self.at_value(candidate, x), cache[x], len(cache)

    def fits(self, jobs: list[tuple]) -> list[tuple[Effect, float, int]]:
        """:meth:`fit` of every (accepted, candidate, grid, best index), on the workers when there are some."""
        if self.workers is None:
            return [self.fit(*job) for job in jobs]
        results, casts = self.workers.fits(jobs)
        self.resim.casts += casts
        return results

    def refit(self, effects: list[Effect], passes: int = 2) -> list[Effect]:
        """Coordinate descent (:meth:`descend`) on the calibration frames, and again from the best point of a
        pairwise grid (:meth:`pair_start`) when that screens better: two effects that dim the returns alike
        trade off along a curved valley that coordinate descent crawls along (sun 400 W/m^2 behind dirt 0.62
        stopped at sun 83 with dirt 0.43, 60 times the true pair's gap). The better fit is kept."""
        effects = self.descend(effects, passes)
        start = self.pair_start(effects)
        if start is not None:
            again = self.descend(start, passes)
            if self.gap(again, "fit") < self.gap(effects, "fit"):
                effects = again
        return effects

    def descend(self, effects: list[Effect], passes: int = 2) -> list[Effect]:
        """Coordinate descent: each effect's main parameter fitted again on the calibration frames
        with the others fixed - over its whole range (grid, then Brent), since an effect found
        alone may have absorbed part of another (dirt dims the spray behind it) - ``passes`` times. An effect
        proven by the data (:meth:`proven_by_data`) stays as it is: refitted, a recorded return mode
        would go to whichever mode fits the calibration frames a hair better."""
        effects = list(effects)
        for _ in range(passes):
            for i, effect in enumerate(effects):
                if self.proven_by_data(effect):
                    continue
                others = effects[:i] + effects[i + 1 :]
                current = np.log(effect.value) if effect.spec.log_search else effect.value
                xs = np.unique(np.append(self.grid_of(effect), current))
                row = self.gaps([(others + [self.at_value(effect, x)], "fit") for x in xs])
                cache = {round(float(x), 6): g for x, g in zip(xs, row)}
                k = int(np.argmin(row))
                effects[i] = self.fit(others, effect, xs, k, cache)[0]
        return effects

    def pair_start(self, effects: list[Effect]) -> list[Effect] | None:
        """The effects with the two weather effects of the best point of every pair's two-dimensional grid on the
        screening frames, the others as they are; None when no grid point screens better than ``effects``
        (or fewer than two weather effects are fitted: the sensor family's keep their values, as in
        :meth:`~lidar_weather_sim.gap.rounds.SearchRounds.joint_round`)."""
        free = [i for i, e in enumerate(effects)
                if e.spec.family == "weather" and not e.spec.categorical and not self.proven_by_data(e)]  # fmt: skip
        jobs = []
        for a, i in enumerate(free):
            for j in free[a + 1 :]:
                for x in self.grid_of(effects[i]):
                    for y in self.grid_of(effects[j]):
                        trial = list(effects)
                        trial[i], trial[j] = self.at_value(effects[i], x), self.at_value(effects[j], y)
                        jobs.append(trial)
        if not jobs:
            return None
        row = self.gaps([(trial, "screen") for trial in jobs] + [(list(effects), "screen")])
        k = int(np.argmin(row[:-1]))
        return jobs[k] if row[k] < row[-1] else None
