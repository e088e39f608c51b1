"""The gap search's rounds (the steps of :mod:`lidar_weather_sim.gap.search`), each returning its candidates.

- :meth:`SearchRounds.read_off_round`: the effects read off the recording, tried first, each in turn;
- :meth:`SearchRounds.screen_round`: every candidate screened on its grid with the accepted effects fixed, the
  most promising refined on the calibration frames, all scored on the held-out frames;
- :meth:`SearchRounds.joint_round`: the same with the accepted weather effects free;
- :meth:`SearchRounds.swap_round`: the joint round without the last accepted weather effect.
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.gap.diagnosis import Candidate, Diagnosis, same_effect
from lidar_weather_sim.gap.fitting import EffectFitter
from lidar_weather_sim.gap.resim import GapResimulator
from lidar_weather_sim.scenario.effects import EFFECTS, Effect, conflicts, spray_candidates


def candidate_effects(resim: GapResimulator, families: tuple[str, ...] = ("weather",)) -> list[Effect]:
    """One untuned effect per name of ``families`` (the spray once per vehicle), at the middle of its bounds;
    not the effects read off the data (:attr:`~lidar_weather_sim.gap.evaluation.GapEvaluator.data_candidates`)."""
    out = []
    for name, spec in EFFECTS.items():
        if spec.family not in families or spec.from_data:
            continue
        mid = float(np.sqrt(spec.bounds[0] * spec.bounds[1]) if spec.log_search else np.mean(spec.bounds))
        if spec.categorical:
            out.append(Effect(name, {spec.main: spec.choices[0]}))
        elif name == "spray":
            out += [Effect(name, {spec.main: mid, "actor": actor}) for actor in spray_candidates(resim.scenario)]
        else:
            out.append(Effect(name, {spec.main: mid}))
    return out


def refined_ranks(swaps: list[bool], refine: int) -> list[int]:
    """Which candidates of a joint round, ranked by their screened gap (``swaps``: each one replaces an accepted
    effect), are refined: the best ``refine``, and every replacement. A replacement is screened on its coarse grid
    against the refitted effect it replaces, so it ranks behind candidates that change little (draw case 24: rain
    on its 5 values in place of a refitted snow, behind a spray at its floor and water in place of the dirt);
    refined, it may win. Conflicts are few (rain or snow, dirt or water), so are replacements."""
    return list(range(min(refine, len(swaps)))) + [r for r, swap in enumerate(swaps) if swap and r >= refine]


def reachable_gap(xs: np.ndarray, row: list[float], k: int) -> float:
    """The gap a candidate's refinement may reach from its screening ``row`` (gaps at the grid values ``xs``, the
    best at ``k``): at an inner grid point the vertex of the parabola through it and its two neighbours, else the
    best grid gap. A sensor effect's grid holds its identity value (gamma 1, scale 1, bias 0): a gamma of 0.857
    screens best there, no better than without it, and lost the refinement to effects at the edge of their
    range that screen a hair better by noise (VLP-16 draw 8 of config/sensor_effect_cases.yaml named nothing);
    the curvature around its grid point shows what refining it can gain."""
    if not 0 < k < len(xs) - 1:
        return row[k]
    a, b, c = np.polyfit(np.asarray(xs[k - 1 : k + 2], float), np.asarray(row[k - 1 : k + 2], float), 2)
    return float(min(row[k], c - b * b / (4.0 * a))) if a > 0 else row[k]


class SearchRounds(EffectFitter):
    """The rounds of the module doc on the evaluations, fits and acceptance rule of its bases."""

    def round_candidates(self, accepted: list[Effect], excluded: list[Effect] = (),
                         swaps: bool = False) -> list[tuple[Effect, list[Effect]]]:  # fmt: skip
        """The candidate effects of a round, each with the accepted effects it goes with: every effect of the
        searched families and those read off the data, but those accepted or ``excluded``, a recorded return
        mode, and those conflicting with the accepted; with ``swaps``, one that conflicts with a single accepted
        effect (not proven by the data) goes with the others instead."""
        read_off = [c for c in self.data_candidates if c.spec.from_data]  # the others: on the rounds' grids anyway
        known = ["sensor.return_mode"] if self.recorded_mode is not None else []  # recorded: not searched
        out = []
        for c in candidate_effects(self.resim, self.families) + read_off:
            if any(same_effect(c, a) for a in [*accepted, *excluded]) or c.name in known:
                continue
            base = list(accepted) if conflicts(accepted + [c]) is None else None
            if base is None and swaps:
                kept = [a for a in accepted if conflicts([a, c]) is None]
                gone = [a for a in accepted if conflicts([a, c]) is not None]
                if len(gone) == 1 and not self.proven_by_data(gone[0]) and conflicts(kept + [c]) is None:
                    base = kept
            if base is not None:
                out.append((c, base))
        return out

    def read_off_round(self, diag: Diagnosis, current: float) -> tuple[float, list[Effect]]:
        """The first trial of the effects read off the data (search step 3), in turn, each accepted under the
        acceptance rule on the held-out frames; returns the held-out gap and the effects accepted."""
        accepted: list[Effect] = []
        tried = []
        for effect in self.data_candidates:
            held = self.gap(accepted + [effect], "heldout")
            self.progress(f"{effect.label()} (read off the recording): held-out gap {held:.4f}")
            candidate = Candidate(effect, float("nan"), held, 1)
            tried.append(candidate)
            if self.earns_margin(effect, held, current) or self.holds_on_redraws(effect, accepted):
                diag.accepted.append((candidate, current))
                accepted.append(effect)
                current = held
        if tried:
            diag.rounds.append(tried)
        return current, accepted

    def screen_round(self, accepted: list[Effect], excluded: list[Effect] = ()) -> list[Candidate]:
        """Screen every candidate (but those ``excluded``) on its grid, refine the best ``refine`` (with the sensor
        family the most promising: :func:`reachable_gap`), score all on the held-out frames; the evaluations of
        each step are independent (and run on the workers when there are some)."""
        options = [c for c, _ in self.round_candidates(accepted, excluded)]
        grids = [self.grid_of(c) for c in options]
        gaps = iter(self.gaps([(accepted + [self.at_value(c, x)], "screen") for c, xs in zip(options, grids) for x in xs]))
        screened = []
        for c, xs in zip(options, grids):
            row = [next(gaps) for _ in xs]
            k = int(np.argmin(row))
            rank = reachable_gap(xs, row, k) if "sensor" in self.families and not c.spec.categorical else row[k]
            screened.append((c, self.at_value(c, xs[k]), row[k], xs, k, rank))
        order = sorted(range(len(screened)), key=lambda i: screened[i][5])
        best = [(accepted, screened[i][0], screened[i][3], screened[i][4]) for i in order[: self.refine]]
        fits = self.fits(best)
        fitted = [(fits[rank] if rank < len(fits) else (screened[i][1], screened[i][2], 0)) for rank, i in enumerate(order)]
        heldout = self.gaps([(accepted + [effect], "heldout") for effect, _, _ in fitted])
        out = []
        for (effect, gap, n), held in zip(fitted, heldout):
            out.append(Candidate(effect, gap, held, self.grid + n))
            self.progress(f"{effect.label()}: held-out gap {held:.4f}")
        return out

    def joint_round(self, accepted: list[Effect], excluded: list[Effect] = ()) -> list[Candidate]:
        """:meth:`screen_round` with the accepted effects free, for when no candidate qualifies with them fixed: an
        effect accepted alone may have absorbed part of the one still missing, and next to it that one no longer
        helps (a dirt of 0.36 accepted for a sun of 400 W/m^2 behind a dirt of 0.62: both dim the returns). Each
        candidate's grid values are screened with each accepted weather effect in turn on its whole grid, the
        others as accepted (with one accepted effect: the full two-dimensional grid; the sensor family's effects
        keep their values: read off the data, or on 7-value grids that would make the round 8 times a plain
        one); the best ``refine`` (and every one that replaces an accepted effect, :func:`refined_ranks`) are refined
        from there with the accepted effects at their screened values, and every one is scored on the held-out
        frames with them. A candidate that conflicts with one accepted effect is tried in
        its place (:meth:`round_candidates`): the first of two effects that cannot go together may have been
        accepted for the other (snow at 0.7 mm/h for rain at 21 mm/h behind a dirty cover), which then can no
        longer be tried."""
        sets = []  # per candidate: (it, its grid, [(the accepted effects of a job, its grid index in that job)], swap)
        for c, base in self.round_candidates(accepted, excluded, swaps=True):
            xs = self.grid_of(c)
            variants = [(list(base), k) for k in range(len(xs))]
            for i, e in enumerate(base):
                if e.spec.family == "weather" and not e.spec.categorical:
                    variants += [(base[:i] + [self.at_value(e, y)] + base[i + 1 :], k)
                                 for y in self.grid_of(e) for k in range(len(xs))]  # fmt: skip
            if len(variants) > len(xs) or len(base) < len(accepted):
                sets.append((c, xs, variants, len(base) < len(accepted)))
        gaps = iter(self.gaps([(others + [self.at_value(c, xs[k])], "screen")
                               for c, xs, variants, _ in sets for others, k in variants]))  # fmt: skip
        screened = []
        for c, xs, variants, swap in sets:
            row = [next(gaps) for _ in variants]
            j = int(np.argmin(row))
            others, k = variants[j]
            screened.append((c, others, xs, k, row[j], len(row), swap))
        screened.sort(key=lambda s: s[4])
        chosen = refined_ranks([s[6] for s in screened], self.refine)
        jobs = [(others, c, xs, k) for c, others, xs, k, *_ in (screened[r] for r in chosen)]
        fits = dict(zip(chosen, self.fits(jobs)))
        fitted = [(others, *(fits[r] if r in fits else (self.at_value(c, xs[k]), gap, 0)), n)
                  for r, (c, others, xs, k, gap, n, _) in enumerate(screened)]  # fmt: skip
        heldout = self.gaps([(others + [effect], "heldout") for others, effect, _, _, _ in fitted])
        out = []
        for (others, effect, gap, n, screens), held in zip(fitted, heldout):
            out.append(Candidate(effect, gap, held, screens + n, tuple(others)))
            self.progress(f"{effect.label()} with {', '.join(e.label() for e in others) or 'nothing'} free: "
                          f"held-out gap {held:.4f}")  # fmt: skip
        return out

    def swap_round(self, accepted: list[Effect], excluded: list[Effect] = ()) -> list[Candidate]:
        """:meth:`joint_round` without the last accepted effect (and not offering it), for when neither a plain nor a
        joint round qualifies and it is a fitted weather effect accepted after another: an effect accepted alone
        may have imitated the missing one, and the next one accepted beside it then fits what is left over (fog
        107 m behind a dirt of 0.66: fog at 594 m imitated the near field the dirt dims, then a sun of 126 W/m^2
        qualified, where fog and dirt together leave a quarter of their gap). A candidate of this round
        replaces that effect when it beats the gap with it by the margin. Empty when there is no such effect
        (one round with the others free costs about 6 plain rounds)."""
        fitted = [e for e in accepted
                  if e.spec.family == "weather" and not e.spec.categorical and not self.proven_by_data(e)]  # fmt: skip
        if len(fitted) < 2 or accepted[-1] is not fitted[-1]:
            return []
        self.progress(f"without {accepted[-1].label()}:")
        return self.joint_round(accepted[:-1], [*excluded, accepted[-1]])
