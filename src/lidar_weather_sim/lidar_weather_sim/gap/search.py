"""``lidar-weather-sim gap``: measure the reality gap of a recording, name the missing effects, fit them.

1. The recording's frames are split by index: even frames calibrate, odd frames are held
   out (or as a twin's split.yaml says, :mod:`lidar_weather_sim.gap.split`: its frames, or for a
   sector split the same frames with the calibration and held-out azimuth sectors' points). Up to ``fit_frames`` evenly spaced calibration frames are used for fitting and up to
   ``heldout_frames`` held-out frames for every decision.
2. The gap is :func:`lidar_weather_sim.gap.signatures.gap_value` between the measured frames
   and the same frames re-simulated from the recorded poses (:mod:`lidar_weather_sim.gap.resim`).
3. Each round, every candidate effect the model knows (:data:`lidar_weather_sim.gap.effects.EFFECTS`;
   spray once per vehicle of the scenario) that does not conflict with those already
   accepted is screened: its main parameter is tried on a grid of ``grid`` values over its
   bounds (log-spaced where the effect spans decades) on ``screen_frames`` of the
   calibration frames. The ``refine`` candidates that screen best are then fitted on all
   calibration frames by bounded Brent minimisation (scipy) between the grid neighbours of
   their best value. Every candidate is scored on the held-out frames at its best value.
4. The candidate with the lowest held-out gap is accepted if it shrinks the current
   held-out gap by at least ``min_gain`` (10 %) and by at least ``min_abs_gain`` (0.002:
   below that the change is at the level of what re-drawing the measurement's noise
   moves the gap, e.g. 0.004-0.008 for the nuisance of ``make-measured``); the accepted
   effects are then refitted together, and the new effect is kept only if the refitted set
   still meets that rule on the held-out frames (otherwise its gain was fitting noise that
   the joint fit takes back); rounds repeat until no candidate qualifies. The other
   candidates of the last round are reported as rejected with their held-out gap.
5. Backward elimination (:meth:`GapSearch.prune`): each accepted effect must still be worth
   that margin with all the others in place; one that is not (a weak effect accepted early,
   made redundant by a later one) is dropped and the rest refitted.

Cost: the budgets do not grow with the recording, so a diagnosis casts about
``(candidates x (grid x screen_frames + heldout_frames) + refine x 10 x fit_frames)``
frames per round, whatever the length of the recording.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.optimize import minimize_scalar

from lidar_weather_sim.gap.budgets import FIT_FRAMES, HELDOUT_FRAMES, SCREEN_FRAMES
from lidar_weather_sim.gap.effects import EFFECTS, Effect, conflicts, search_grid, spray_candidates
from lidar_weather_sim.gap.resim import Resimulator, measured_signature
from lidar_weather_sim.gap.signatures import Signature, gap_value
from lidar_weather_sim.gap.split import DataSplit

MIN_GAIN = 0.10
MIN_ABS_GAIN = 0.002


@dataclass
class Candidate:
    """A fitted candidate: the effect at its best value, its calibration and held-out gaps."""

    effect: Effect
    fit_gap: float
    heldout_gap: float
    evaluations: int


@dataclass
class Diagnosis:
    gap_before: float
    gap_after: float
    accepted: list[tuple[Candidate, float]] = field(default_factory=list)  # (candidate, gap before it)
    rejected: list[Candidate] = field(default_factory=list)
    rounds: list[list[Candidate]] = field(default_factory=list)
    fit_indices: list[int] = field(default_factory=list)
    heldout_indices: list[int] = field(default_factory=list)

    @property
    def effects(self) -> list[Effect]:
        return [c.effect for c, _ in self.accepted]


def _thin(indices: list[int], budget: int) -> list[int]:
    """At most ``budget`` of ``indices``, evenly spaced."""
    if len(indices) <= budget:
        return list(indices)
    return [indices[int(k)] for k in np.linspace(0, len(indices) - 1, budget).round()]


def split_frames(n: int, fit_frames: int, heldout_frames: int, split: DataSplit | None = None) -> tuple[list[int], list[int]]:
    """Calibration (even) and held-out (odd) frame indices, each thinned evenly to its budget; with a
    ``split`` (a twin's split.yaml), its parts' frames instead (the same frames for a sector split)."""
    thin = _thin
    for name, budget in (("fit_frames", fit_frames), ("heldout_frames", heldout_frames)):
        if budget < 1:
            raise ValueError(f"gap: {name} must be at least 1, got {budget}")
    if split is not None:
        beyond = [i for i in split.calibration_frames + split.heldout_frames if not 0 <= i < n]
        if beyond:
            raise ValueError(f"gap: the split names frames {beyond[:5]} but the recording has {n} frames")
        return thin(split.calibration_frames, fit_frames), thin(split.heldout_frames, heldout_frames)
    if n < 2:
        raise ValueError(f"gap needs at least 2 frames with poses (one to fit, one held out), the recording has {n}")
    return thin(list(range(0, n, 2)), fit_frames), thin(list(range(1, n, 2)), heldout_frames)


def candidate_effects(resim: Resimulator) -> list[Effect]:
    """One untuned effect per name (the spray once per vehicle), at the middle of its bounds."""
    out = []
    for name, spec in EFFECTS.items():
        mid = float(np.sqrt(spec.bounds[0] * spec.bounds[1]) if spec.log_search else np.mean(spec.bounds))
        if name == "spray":
            out += [Effect(name, {spec.main: mid, "actor": actor}) for actor in spray_candidates(resim.scenario)]
        else:
            out.append(Effect(name, {spec.main: mid}))
    return out


class GapSearch:
    """The diagnosis of :mod:`lidar_weather_sim.gap.search` over one recording and scenario."""

    def __init__(self, resim: Resimulator, fit_frames: int = FIT_FRAMES, heldout_frames: int = HELDOUT_FRAMES,
                 screen_frames: int = SCREEN_FRAMES,
                 grid: int = 5, refine: int = 2, min_gain: float = MIN_GAIN, min_abs_gain: float = MIN_ABS_GAIN,
                 progress: Callable[[str], None] | None = None, split: DataSplit | None = None) -> None:  # fmt: skip
        self.resim = resim
        self.split = split
        self.grid = grid
        self.refine = refine
        self.min_gain = min_gain
        self.min_abs_gain = min_abs_gain
        self.progress = progress or (lambda text: None)
        rec = resim.recording
        self.fit_idx, self.held_idx = split_frames(len(rec.frames), fit_frames, heldout_frames, split)
        self.screen_idx = self.fit_idx[:: max(1, len(self.fit_idx) // max(screen_frames, 1))][:screen_frames]
        self._measured = {name: measured_signature(rec, idx, resim.contexts, resim.channels, self.keep(name))
                          for name, idx in self._splits().items()}  # fmt: skip

    def _splits(self) -> dict[str, list[int]]:
        return {"screen": self.screen_idx, "fit": self.fit_idx, "heldout": self.held_idx}

    def keep(self, split: str) -> Callable[[np.ndarray], np.ndarray] | None:
        """The point mask of ``split`` under a sector split (None: every point of its frames)."""
        if self.split is None or self.split.kind == "frames":
            return None
        part = "heldout" if split == "heldout" else "calibration"
        return lambda points: self.split.keep(points, part)

    def gap(self, effects: list[Effect], split: str) -> float:
        """Gap between the measured and the simulated frames of ``split`` (screen, fit, heldout);
        on the calibration splits not clipped at 0, so fits can still tell near-perfect values apart."""
        sim: Signature = self.resim.signature(effects, self._splits()[split], self.keep(split))
        return gap_value(self._measured[split], sim, clip=split == "heldout")

    def _objective(self, accepted: list[Effect], candidate: Effect, split: str, cache: dict[float, float]):
        spec = candidate.spec
        lo, hi = spec.bounds

        def value(x: float) -> float:
            return float(np.clip(np.exp(x), lo, hi)) if spec.log_search else float(x)

        def objective(x: float) -> float:
            key = round(float(x), 6)
            if key not in cache:
                cache[key] = self.gap(accepted + [candidate.with_value(value(x))], split)
            return cache[key]

        return objective, value

    def screen(self, accepted: list[Effect], candidate: Effect) -> tuple[Effect, float, np.ndarray, int]:
        """Grid search on the screening frames: (best effect, its gap, the grid in search space, best index)."""
        spec = candidate.spec
        xs = search_grid(spec, self.grid)
        xs = np.log(xs) if spec.log_search else xs
        objective, value = self._objective(accepted, candidate, "screen", {})
        gaps = [objective(x) for x in xs]
        k = int(np.argmin(gaps))
        return candidate.with_value(value(xs[k])), gaps[k], xs, k

    def fit(self, accepted: list[Effect], candidate: Effect, xs: np.ndarray, k: int,
            cache: dict[float, float] | None = None) -> tuple[Effect, float, int]:  # fmt: skip
        """Brent refinement on the calibration frames between the grid neighbours of ``xs[k]``
        (``cache``: calibration gaps already known, by search-space value)."""
        spec = candidate.spec
        cache = {} if cache is None else cache
        objective, value = self._objective(accepted, candidate, "fit", cache)
        objective(xs[k])
        lo, hi = xs[max(k - 1, 0)], xs[min(k + 1, len(xs) - 1)]
        tol = 0.01 if spec.log_search else 0.002 * (spec.bounds[1] - spec.bounds[0])
        minimize_scalar(objective, bounds=(lo, hi), method="bounded", options={"xatol": tol, "maxiter": 10})
        x = min(cache, key=cache.get)
        return candidate.with_value(value(x)), cache[x], len(cache)

    def refit(self, effects: list[Effect], passes: int = 2) -> list[Effect]:
        """Coordinate descent: each effect's main parameter fitted again on the calibration frames
        with the others fixed - over its whole range (grid, then Brent), since an effect found
        alone may have absorbed part of another (dirt dims the spray behind it) - ``passes`` times."""
        effects = list(effects)
        for _ in range(passes):
            for i, effect in enumerate(effects):
                spec = effect.spec
                cache: dict[float, float] = {}
                objective, value = self._objective(effects[:i] + effects[i + 1 :], effect, "fit", cache)
                xs = search_grid(spec, self.grid)
                xs = np.sort(np.append(np.log(xs) if spec.log_search else xs,
                                       np.log(effect.value) if spec.log_search else effect.value))  # fmt: skip
                k = int(np.argmin([objective(x) for x in xs]))
                effects[i] = self.fit(effects[:i] + effects[i + 1 :], effect, xs, k, cache)[0]
        return effects

    def run_round(self, accepted: list[Effect]) -> list[Candidate]:
        options = [c for c in candidate_effects(self.resim)
                   if not any(_same(c, a) for a in accepted) and conflicts(accepted + [c]) is None]  # fmt: skip
        screened = [(c, *self.screen(accepted, c)) for c in options]
        order = sorted(range(len(screened)), key=lambda i: screened[i][2])
        out = []
        for rank, i in enumerate(order):
            candidate, effect, gap, xs, k = screened[i]
            evaluations = self.grid
            if rank < self.refine:
                effect, gap, n = self.fit(accepted, candidate, xs, k)
                evaluations += n
            out.append(Candidate(effect, gap, self.gap(accepted + [effect], "heldout"), evaluations))
            self.progress(f"{effect.label()}: held-out gap {out[-1].heldout_gap:.4f}")
        return out

    def run(self) -> Diagnosis:
        before = self.gap([], "heldout")
        diag = Diagnosis(before, before, fit_indices=self.fit_idx, heldout_indices=self.held_idx)
        current, accepted = before, []
        self.progress(f"gap before: {before:.4f}")
        while True:
            fitted = self.run_round(accepted)
            if not fitted:
                break
            diag.rounds.append(fitted)
            best = min(fitted, key=lambda c: c.heldout_gap)
            required = min(current * (1.0 - self.min_gain), current - self.min_abs_gain)
            if best.heldout_gap > required:
                diag.rejected = fitted
                break
            if accepted:  # the earlier effects were fitted without this one: refit them with it
                refitted = self.refit(accepted + [best.effect])
                heldout = self.gap(refitted, "heldout")
                self.progress(f"refitted: {', '.join(e.label() for e in refitted)}: held-out gap {heldout:.4f}")
                if heldout > required:  # its gain does not survive the joint fit: it was fitting noise
                    diag.rejected = fitted
                    break
                accepted = refitted
                best = Candidate(accepted[-1], best.fit_gap, heldout, best.evaluations)
                diag.accepted = [(Candidate(e, c.fit_gap, c.heldout_gap, c.evaluations), g)
                                 for e, (c, g) in zip(accepted, diag.accepted)]  # fmt: skip
            else:
                accepted = [best.effect]
            diag.accepted.append((best, current))
            current = best.heldout_gap
            diag.rejected = [c for c in fitted if c is not best]
        diag.gap_after = self.prune(diag, current)
        return diag

    def prune(self, diag: Diagnosis, current: float) -> float:
        """Backward elimination: an accepted effect stays only if the held-out gap without it (the
        others as fitted) is worse by the margin a new effect must win (``min_gain`` and
        ``min_abs_gain``); else it is dropped, reported as rejected, and the rest refitted. A small
        effect accepted early can become redundant once a later one explains the same residual.
        Returns the held-out gap of what stays."""
        while len(diag.accepted) > 1:
            effects = diag.effects
            without = [self.gap(effects[:i] + effects[i + 1 :], "heldout") for i in range(len(effects))]
            worth = [current <= min(w * (1.0 - self.min_gain), w - self.min_abs_gain) for w in without]
            if all(worth):
                break
            i = min((k for k in range(len(effects)) if not worth[k]), key=lambda k: without[k])
            dropped, _ = diag.accepted.pop(i)
            diag.rejected.append(Candidate(dropped.effect, dropped.fit_gap, current, dropped.evaluations))
            refitted = self.refit(diag.effects)
            current = self.gap(refitted, "heldout")
            self.progress(f"dropped {dropped.effect.label()} (held-out gap without it {without[i]:.4f}); "
                          f"refitted: {', '.join(e.label() for e in refitted)}: held-out gap {current:.4f}")  # fmt: skip
            diag.accepted = [(Candidate(e, c.fit_gap, c.heldout_gap, c.evaluations), g)
                             for e, (c, g) in zip(refitted, diag.accepted)]  # fmt: skip
        return current


def _same(a: Effect, b: Effect) -> bool:
    """The same effect (and the same emitter for spray)."""
    return a.name == b.name and a.params.get("actor") == b.params.get("actor")
