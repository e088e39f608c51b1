"""``lidar-weather-sim gap``: measure the reality gap of a recording, name the missing effects, fit them.

1. The recording's frames are split by index: even frames calibrate, odd frames are held
   out (or as a twin's split.yaml says, :mod:`lidar_weather_sim.gap.split`: its frames, or for a
   sector split the same frames with the calibration and held-out azimuth sectors' points). Up to
   ``fit_frames`` evenly spaced calibration frames are used for fitting and up to ``heldout_frames`` held-out
   frames for every decision (:mod:`lidar_weather_sim.gap.frames`).
2. The gap is :func:`lidar_weather_sim.gap.signatures.gap_value` between the measured frames
   and the same frames re-simulated from the recorded poses (:mod:`lidar_weather_sim.gap.evaluation`,
   :mod:`lidar_weather_sim.gap.resim`).
3. Read-off round (:meth:`~lidar_weather_sim.gap.rounds.SearchRounds.read_off_round`). With the sensor family,
   the effects read off the recording (:mod:`lidar_weather_sim.gap.read_off`: dead and weak channels,
   elevation offsets, the beams' origin at the value the points' elevations show, the near-field ghost at the
   rate its cover-zone count shows) are tried first, each in turn on the held-out frames under the
   rule of step 4: they are what the data shows, not fits, and a fitted effect accepted before them can
   absorb their residual at a wrong value (a wide range noise smearing an offset channel's ranges), after
   which they no longer earn the margin. One that does not earn it is tried again in the screening rounds.
   Dead channels are proven by the data (:meth:`~lidar_weather_sim.gap.acceptance.AcceptanceRule.earns_margin`):
   accepted and kept unless they make the gap worse. So is the return mode the points' ``return_type`` codes
   name (:mod:`lidar_weather_sim.gap.return_modes`): a recording that says its mode is not searched for one
   (two modes can give the same points).
   Screening round (:meth:`~lidar_weather_sim.gap.rounds.SearchRounds.screen_round`): every candidate effect
   the model knows (:data:`lidar_weather_sim.scenario.effects.EFFECTS`; spray once per vehicle of the
   scenario) that does not conflict with those already accepted is screened: its main parameter is tried on a
   grid of ``grid`` values (5; 7 with the sensor family: :data:`~lidar_weather_sim.gap.evaluation.SENSOR_GRID`)
   over its bounds (log-spaced where the effect spans decades) on ``screen_frames`` of the
   calibration frames. The ``refine`` candidates that screen best are then fitted on all
   calibration frames by bounded Brent minimisation (scipy) between the grid neighbours of
   their best value (:mod:`lidar_weather_sim.gap.fitting`). Every candidate is scored on the held-out frames
   at its best value.
4. Acceptance (:mod:`lidar_weather_sim.gap.acceptance`). The candidate with the lowest held-out gap is accepted
   if it shrinks the current held-out gap by at least ``min_gain`` (10 %) and by at least ``min_abs_gain``
   (0.002: below that the change is at the level of what re-drawing the measurement's noise
   moves the gap, e.g. 0.004-0.008 for the nuisance of ``make-measured``); the accepted
   effects are then refitted together, and the new effect is kept only if the refitted set
   still meets that rule on the held-out frames (otherwise its gain was fitting noise that
   the joint fit takes back). With the sensor family it must also meet the rule on the mean
   over independent redraws of every random process of the held-out re-simulation
   (:meth:`~lidar_weather_sim.gap.acceptance.AcceptanceRule.confirmed_on_redraws`): the best of a dozen
   candidates on one held-out draw is chosen by that draw's noise too, and a sensor effect at the edge of its
   range (a 3 mm range noise on a unit's 1.5 cm) can win by that noise alone; the round is then run again
   without it (until another effect is accepted), as it may have hidden the right effect from
   the refinement. When no candidate qualifies next to the accepted effects as fitted, the round is run
   again with them free (:meth:`~lidar_weather_sim.gap.rounds.SearchRounds.joint_round`): an effect accepted
   alone may have absorbed part of the missing one (dirt fitted at 0.36 for sun behind a dirt of 0.62), and
   next to it the missing one no longer helps. When that does not qualify either, it is run once more without
   the last accepted weather effect (:meth:`~lidar_weather_sim.gap.rounds.SearchRounds.swap_round`), whose
   place a candidate takes if it beats the gap with it by the margin: the first effect may have imitated the
   missing one and the last fitted the leftover.
   Rounds repeat until no candidate qualifies. The other candidates of the
   last round are reported as rejected with their held-out gap.
5. Pruning round (:meth:`GapSearch.prune_round`, backward elimination): each accepted effect must still be
   worth that margin with all the others in place; one that is not (a weak effect accepted early,
   made redundant by a later one) is dropped and the rest refitted.

Cost: the budgets do not grow with the recording, so a diagnosis casts about
``(candidates x (grid x screen_frames + heldout_frames) + refine x 10 x fit_frames)``
frames per round, whatever the length of the recording; a round with the accepted effects free screens
``grid x (1 + grid x free effects)`` values per candidate instead of ``grid``.
"""

from __future__ import annotations

from lidar_weather_sim.gap.diagnosis import Candidate, Diagnosis, same_effect
from lidar_weather_sim.gap.rounds import SearchRounds
from lidar_weather_sim.scenario.effects import Effect


class GapSearch(SearchRounds):
    """The diagnosis of the module doc over one recording and scenario: :meth:`run` drives the rounds of
    :mod:`lidar_weather_sim.gap.rounds` and ends with :meth:`prune_round`."""

    def run(self) -> Diagnosis:
        before = self.gap([], "heldout")
        diag = Diagnosis(before, before, fit_indices=self.fit_idx, heldout_indices=self.held_idx)
        current, accepted = before, []
        self.progress(f"gap before: {before:.4f}")
        current, accepted = self.read_off_round(diag, current)
        unconfirmed: list[Effect] = []  # not confirmed on the redraws: left out until another effect is accepted
        while True:
            fitted = self.screen_round(accepted, unconfirmed)
            if not fitted:
                break
            diag.rounds.append(fitted)
            best = min(fitted, key=lambda c: c.heldout_gap)
            required = self.gap_to_beat(current)
            if best.heldout_gap > required and accepted and required >= 0:  # below 0: no gap can qualify
                for round_ in (self.joint_round, self.swap_round):  # the swap only when the joint round fails
                    joint = round_(accepted, unconfirmed)
                    if joint and min(c.heldout_gap for c in joint) <= required:
                        diag.rounds.append(joint)
                        fitted, best = joint, min(joint, key=lambda c: c.heldout_gap)
                        break
            if best.heldout_gap > required:
                diag.rejected = fitted
                break
            if accepted:  # the earlier effects were fitted without this one: refit them with it
                refitted = self.refit(list(accepted if best.companions is None else best.companions) + [best.effect])
                heldout = self.gap(refitted, "heldout")
                self.progress(f"refitted: {', '.join(e.label() for e in refitted)}: held-out gap {heldout:.4f}")
                if heldout > required:  # its gain does not survive the joint fit: it was fitting noise
                    diag.rejected = fitted
                    break
            else:
                refitted, heldout = [best.effect], best.heldout_gap
            if not self.confirmed_on_redraws(accepted, refitted):  # its gain was the held-out draw's noise: try the others
                unconfirmed.append(best.effect)
                diag.rejected = fitted
                continue
            unconfirmed = []
            accepted = refitted
            best = Candidate(accepted[-1], best.fit_gap, heldout, best.evaluations)
            kept = [(c, g) for c, g in diag.accepted if any(same_effect(c.effect, e) for e in accepted)]  # but a swap's
            diag.accepted = [(Candidate(e, c.fit_gap, c.heldout_gap, c.evaluations), g)
                             for e, (c, g) in zip(accepted, kept)]  # fmt: skip
            diag.accepted.append((best, current))
            current = best.heldout_gap
            diag.rejected = [c for c in fitted if c is not best]
        diag.gap_after = self.prune_round(diag, current)
        return diag

    def prune_round(self, diag: Diagnosis, current: float) -> float:
        """Backward elimination: an accepted effect stays only if the held-out gap without it (the
        others as fitted) is worse by the margin a new effect must win (``min_gain`` and
        ``min_abs_gain``); else it is dropped, reported as rejected, and the rest refitted. A small
        effect accepted early can become redundant once a later one explains the same residual.
        Returns the held-out gap of what stays."""
        while len(diag.accepted) > 1:
            effects = diag.effects
            subsets = [effects[:i] + effects[i + 1 :] for i in range(len(effects))]
            without, now, where = self.gaps([(subset, "heldout") for subset in subsets]), current, "held-out"
            worth = [self.earns_margin(e, now, w) for e, w in zip(effects, without)]
            single = [w or self.proven_by_data(e) for e, w in zip(effects, worth)]  # proven by the data: on the redraws
            if "sensor" in self.families and all(single):  # and on the redraws, as an effect is accepted
                now, *without = self.mean_over_redraws([effects] + subsets)
                where = f"mean over redraws ({now:.4f} with it),"
                worth = [self.earns_margin(e, now, w) for e, w in zip(effects, without)]
            if all(worth):
                break
            i = min((k for k in range(len(effects)) if not worth[k]), key=lambda k: without[k])
            dropped, _ = diag.accepted.pop(i)
            diag.rejected.append(Candidate(dropped.effect, dropped.fit_gap, current, dropped.evaluations))
            refitted = self.refit(diag.effects)
            current = self.gap(refitted, "heldout")
            self.progress(f"dropped {dropped.effect.label()} ({where} gap without it {without[i]:.4f}); "
                          f"refitted: {', '.join(e.label() for e in refitted)}: held-out gap {current:.4f}")  # fmt: skip
            diag.accepted = [(Candidate(e, c.fit_gap, c.heldout_gap, c.evaluations), g)
                             for e, (c, g) in zip(refitted, diag.accepted)]  # fmt: skip
        return current
