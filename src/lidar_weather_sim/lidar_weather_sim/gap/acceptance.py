"""The gap search's acceptance rule: when an effect set beats another on the held-out frames.

An effect set must shrink the held-out gap by at least ``min_gain`` (10 %) and by at least ``min_abs_gain``
(0.002: below that the change is at the level of what re-drawing the measurement's noise moves the gap).
An effect the data alone proves (:meth:`~lidar_weather_sim.gap.evaluation.GapEvaluator.proven_by_data`) needs
only not to make the gap worse. With the sensor family a decision must also hold on the mean over independent
redraws of the held-out re-simulation (:meth:`AcceptanceRule.confirmed_on_redraws`).
"""

from __future__ import annotations

from lidar_weather_sim.gap.evaluation import GapEvaluator
from lidar_weather_sim.scenario.effects import Effect


class AcceptanceRule(GapEvaluator):
    """The evaluations with the rule of the module doc."""

    def gap_to_beat(self, current: float) -> float:
        """The held-out gap an effect set must reach to beat one at ``current``: ``min_gain`` and ``min_abs_gain``."""
        return min(current * (1.0 - self.min_gain), current - self.min_abs_gain)

    def earns_margin(self, effect: Effect, held: float, current: float) -> bool:
        """Whether ``effect`` earns its place: the held-out gap with it (``held``) meets :meth:`gap_to_beat` of the
        gap without it (``current``). An effect proven by the data (a channel silent in every calibration frame
        where the model returns on it, or the return mode the recording's codes name) needs only not to make the
        gap worse: two of 128 channels move the gap by about the margin, less than what the counts themselves
        prove, and ``dual`` on a two-echo sensor changes no point."""
        return held <= (current if self.proven_by_data(effect) else self.gap_to_beat(current))

    def holds_on_redraws(self, effect: Effect, accepted: list[Effect]) -> bool:
        """Whether ``effect``, proven by the data, does not make the held-out gap worse on the mean over the
        redraws (:meth:`mean_over_redraws`): with no margin to win, one held-out draw's noise (about 0.003)
        decides otherwise. False for other effects and without the sensor family."""
        if not self.proven_by_data(effect) or "sensor" not in self.families:
            return False
        with_it, without = self.mean_over_redraws([accepted + [effect], accepted])
        self.progress(f"{effect.label()}: mean over redraws {with_it:.4f} with it, {without:.4f} without")
        return with_it <= without

    def confirmed_on_redraws(self, before: list[Effect], after: list[Effect]) -> bool:
        """Whether ``after`` still beats ``before`` by the margin on the mean over independent redraws of the
        held-out re-simulation (:meth:`mean_over_redraws`). Sensor family only (search module doc, step 4);
        always true for the others."""
        if "sensor" not in self.families:
            return True
        was, now = self.mean_over_redraws([before, after])
        verdict = now <= self.gap_to_beat(was)
        self.progress(f"on independent redraws: held-out gap {was:.4f} -> {now:.4f}: "
                      f"{'confirmed' if verdict else 'not confirmed, rejected'}")  # fmt: skip
        return verdict
