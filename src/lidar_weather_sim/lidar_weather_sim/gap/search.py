"""``lidar-weather-sim gap``: measure the reality gap of a recording, name the missing effects, fit them.

1. The recording's frames are split by index: even frames calibrate, odd frames are held
   out (or as a twin's split.yaml says, :mod:`lidar_weather_sim.gap.split`: its frames, or for a
   sector split the same frames with the calibration and held-out azimuth sectors' points). Up to ``fit_frames`` evenly spaced calibration frames are used for fitting and up to
   ``heldout_frames`` held-out frames for every decision.
2. The gap is :func:`lidar_weather_sim.gap.signatures.gap_value` between the measured frames
   and the same frames re-simulated from the recorded poses (:mod:`lidar_weather_sim.gap.resim`).
3. With the sensor family, the effects read off the recording (dead and weak channels, elevation offsets, and
   the beams' origin at the value the points' elevations show: :mod:`lidar_weather_sim.gap.channels`; the
   near-field ghost at the rate its cover-zone count shows: :mod:`lidar_weather_sim.gap.ghost`) are
   tried first, each in turn on the held-out frames under the
   rule of step 4: they are what the data shows, not fits, and a fitted effect accepted before them can
   absorb their residual at a wrong value (a wide range noise smearing an offset channel's ranges), after
   which they no longer earn the margin. One that does not earn it is tried again in the rounds. Dead
   channels are evident (:meth:`GapSearch.worth`): accepted and kept unless they make the gap worse. So is
   the return mode the points' ``return_type`` codes name (:mod:`lidar_weather_sim.gap.return_modes`): a
   recording that says its mode is not searched for one (two modes can give the same points).
   Each round, every candidate effect the model knows (:data:`lidar_weather_sim.scenario.effects.EFFECTS`;
   spray once per vehicle of the scenario) that does not conflict with those already
   accepted is screened: its main parameter is tried on a grid of ``grid`` values (5; 7 with
   the sensor family: :data:`SENSOR_GRID`) over its
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
   the joint fit takes back). With the sensor family it must also meet the rule on the mean
   over independent redraws of every random process of the held-out re-simulation
   (:meth:`GapSearch.confirmed`): the best of a dozen candidates on one held-out draw is
   chosen by that draw's noise too, and a sensor effect at the edge of its range (a 3 mm
   range noise on a unit's 1.5 cm) can win by that noise alone; the round is then run again
   without it (until another effect is accepted), as it may have hidden the right effect from
   the refinement. When no candidate qualifies next to the accepted effects as fitted, the round is run
   again with them free (:meth:`GapSearch.joint_round`): an effect accepted alone may have absorbed part
   of the missing one (dirt fitted at 0.36 for sun behind a dirt of 0.62), and next to it the missing one
   no longer helps. When that does not qualify either, it is run once more without the last accepted
   weather effect (:meth:`GapSearch.swap_round`), whose place a candidate takes if it beats the gap with it
   by the margin: the first effect may have imitated the missing one and the last fitted the leftover.
   Rounds repeat until no candidate qualifies. The other candidates of the
   last round are reported as rejected with their held-out gap.
5. Backward elimination (:meth:`GapSearch.prune`): each accepted effect must still be worth
   that margin with all the others in place; one that is not (a weak effect accepted early,
   made redundant by a later one) is dropped and the rest refitted.

Cost: the budgets do not grow with the recording, so a diagnosis casts about
``(candidates x (grid x screen_frames + heldout_frames) + refine x 10 x fit_frames)``
frames per round, whatever the length of the recording; a round with the accepted effects free screens
``grid x (1 + grid x free effects)`` values per candidate instead of ``grid``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from functools import partial
from typing import Callable

import numpy as np
from scipy.optimize import minimize_scalar

from lidar_weather_sim.core.engine import Engine
from lidar_weather_sim.gap.budgets import FIT_FRAMES, HELDOUT_FRAMES, SCREEN_FRAMES
from lidar_weather_sim.gap.channels import MIN_ORIGIN_M, beam_origin, dead_channels, elevation_offsets, weak_channels
from lidar_weather_sim.scenario.effects import (
    EFFECTS,
    FAMILIES,
    Effect,
    conflicts,
    format_channel_values,
    search_grid,
    spray_candidates,
)
from lidar_weather_sim.gap.ghost import cover_returns, ghost_rate
from lidar_weather_sim.gap.parallel import SearchSource, remote_fit, remote_gap
from lidar_weather_sim.gap.resim import Resimulator, measured_signature
from lidar_weather_sim.gap.return_modes import recorded_return_mode
from lidar_weather_sim.gap.signatures import (
    ELEVATION_SHIFT_SCALE_DEG,
    INTENSITY_SHIFT_SCALE_BYTES,
    RANGE_SHIFT_SCALE_M,
    channel_shift_term,
    gap_value,
    paired_residuals,
    systematic_bray_curtis,
)
from lidar_weather_sim.gap.split import DataSplit

GRID = 5  # screening values per candidate
#: with the sensor family: gamma and scale span 0.25-4, and on 5 values (a factor 2 apart) a gamma of 1.37 screens
#: no better than none at its best value (1), so the refinement went to others (VLP-16 draw 0 of
#: config/sensor_effect_cases.yaml named nothing, or an intensity scale); 7 values are a factor 1.59 apart
SENSOR_GRID = 7
MIN_GAIN = 0.10
GHOST_REDRAWS = (1, 2, 3, 4)  # the model draws averaged for each count of the ghost rate read off the data
MIN_ABS_GAIN = 0.002
REDRAW_SEED_OFFSET = 7919  # the range term's second simulation: the scenario's seed + this (far from make-measured's + 1000)
#: the confirmation's independent redraws (each range term's second simulation: + 7919 more); 3, as one held-out
#: frame's gap moves by ~0.003 from redraw to redraw (VLP-16 on ``ouster_street``), more than the 0.002 margin
CONFIRM_SEED_OFFSETS = (104729, 130363, 156007)


@dataclass
class Candidate:
    """A fitted candidate: the effect at its best value, its calibration and held-out gaps."""

    effect: Effect
    fit_gap: float
    heldout_gap: float
    evaluations: int
    companions: tuple[Effect, ...] | None = None  # the accepted effects as set for it (None: as they were)


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


def candidate_effects(resim: Resimulator, families: tuple[str, ...] = ("weather",)) -> list[Effect]:
    """One untuned effect per name of ``families`` (the spray once per vehicle), at the middle of its bounds;
    not the effects read off the data (:meth:`GapSearch.data_candidates`)."""
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


class GapSearch:
    """The diagnosis of :mod:`lidar_weather_sim.gap.search` over one recording and scenario."""

    def __init__(self, resim: Resimulator, fit_frames: int = FIT_FRAMES, heldout_frames: int = HELDOUT_FRAMES,
                 screen_frames: int = SCREEN_FRAMES,
                 grid: int | None = None, refine: int = 2, min_gain: float = MIN_GAIN, min_abs_gain: float = MIN_ABS_GAIN,
                 progress: Callable[[str], None] | None = None, engine: Engine | None = None,
                 source: SearchSource | None = None, families: tuple[str, ...] = ("weather",),
                 split: DataSplit | None = None) -> None:  # fmt: skip
        """``families``: the effect families searched (:data:`~lidar_weather_sim.scenario.effects.FAMILIES`;
        ``sensor`` adds the unit's own departures, for recordings of real sensors). ``split``: a twin's
        calibration / held-out split (else even / odd frames). ``engine`` with ``source`` (how a worker
        builds this same search): each round's evaluations run on the engine's workers
        (:mod:`lidar_weather_sim.gap.parallel`); without, in this process."""
        unknown = sorted(set(families) - set(FAMILIES))
        if unknown or not families:
            raise ValueError(f"gap: effect families {list(families)}: choose from {', '.join(FAMILIES)}")
        self.families = tuple(families)
        self.resim = resim
        self.split = split
        self.engine = engine if engine is not None and not engine.serial else None
        self.source = source
        self.grid = grid or (SENSOR_GRID if "sensor" in self.families else GRID)
        self.refine = refine
        self.min_gain = min_gain
        self.min_abs_gain = min_abs_gain
        self.progress = progress or (lambda text: None)
        rec = resim.recording
        self.fit_idx, self.held_idx = split_frames(len(rec.frames), fit_frames, heldout_frames, split)
        self.screen_idx = self.fit_idx[:: max(1, len(self.fit_idx) // max(screen_frames, 1))][:screen_frames]
        self._measured = {name: measured_signature(rec, idx, resim.contexts, resim.channels, self.keep(name))
                          for name, idx in self._splits().items()}  # fmt: skip

    @functools.cached_property
    def data_candidates(self) -> list[Effect]:
        """Effects whose value the calibration frames show (:mod:`lidar_weather_sim.gap.channels`: dead and
        weak channels, elevation offsets, the beams' origin; :mod:`lidar_weather_sim.gap.ghost`: the near-field
        ghost rate; :mod:`lidar_weather_sim.gap.return_modes`: the return mode the points' codes name, when it
        is not the scenario's): the recording against its re-simulation without effects and the
        profile's elevation table; sensor family only. Computed on first use, by the driver's rounds (a worker
        that only evaluates gaps never pays the extra re-simulation)."""
        if "sensor" not in self.families:
            return []
        keep = self.keep("fit") or (lambda points: np.ones(len(points), bool))
        measured = [m[keep(m)] for m in (self.resim.recording.frames[i].points for i in sorted(self.fit_idx))]
        simulated = [s[keep(s)] for s in self.resim.frames([], self.fit_idx)]
        profile, channels = self.resim.world.profile, self.resim.channels
        out = []
        dead = dead_channels(measured, simulated, channels)
        if dead:
            out.append(Effect("sensor.dead_channels", {"channels": "+".join(map(str, dead))}))
        weak = weak_channels(measured, simulated, channels, profile.detection.intensity_dynamic_range,
                             profile.scan.columns)
        if weak:
            out.append(Effect("sensor.weak_channels", {"gains": format_channel_values(weak)}))
        nominal = np.array([b.elevation_deg for b in profile.beams])[profile.channel_order]
        offsets = elevation_offsets(measured, nominal)
        if offsets:
            out.append(Effect("sensor.elevation_offsets", {"offsets": format_channel_values(offsets)}))
        recorded = self.recorded_mode
        if recorded is not None and recorded != (self.resim.scenario.sensor.return_mode or profile.detection.return_mode):
            out.append(Effect("sensor.return_mode", {"mode": recorded}))
        up, radial = beam_origin(measured, nominal)
        if abs(up) >= MIN_ORIGIN_M:
            out.append(Effect("sensor.beam_origin", {"z": up}))
        if radial >= MIN_ORIGIN_M:
            out.append(Effect("sensor.beam_origin_radial", {"radius": radial}))
        ghost = EFFECTS["sensor.near_field_ghost"]

        def expected(rate: float) -> float:  # the model's cover-zone count at ``rate``, mean over the draws
            effects = [Effect(ghost.name, {ghost.main: rate})]
            return float(np.mean([cover_returns([f[keep(f)] for f in self.resim.frames(effects, self.fit_idx, redraw=d)])
                                  for d in GHOST_REDRAWS]))  # fmt: skip

        recorded, without = cover_returns(measured), cover_returns(simulated)
        rate = ghost_rate(recorded, without, expected, ghost.bounds, len(GHOST_REDRAWS))
        if rate is not None:
            out.append(Effect(ghost.name, {ghost.main: rate}))
        return out

    @functools.cached_property
    def recorded_mode(self) -> str | None:
        """The return mode the calibration frames' ``return_type`` codes name (sensor family only; None: not
        recorded, the rounds try each)."""
        if "sensor" not in self.families:
            return None
        return recorded_return_mode([self.resim.recording.frames[i].points for i in sorted(self.fit_idx)])

    def evident(self, effect: Effect) -> bool:
        """Whether the data alone proves ``effect`` (:meth:`worth`): dead channels, and the return mode the
        recording's codes name."""
        if effect.name == "sensor.return_mode":
            return effect.params[effect.spec.main] == self.recorded_mode
        return effect.spec.evident

    def _splits(self) -> dict[str, list[int]]:
        return {"screen": self.screen_idx, "fit": self.fit_idx, "heldout": self.held_idx}

    def keep(self, split: str) -> Callable[[np.ndarray], np.ndarray] | None:
        """The point mask of ``split`` under a sector split (None: every point of its frames)."""
        if self.split is None or self.split.kind == "frames":
            return None
        part = "heldout" if split == "heldout" else "calibration"
        return lambda points: self.split.keep(points, part)

    def gap(self, effects: list[Effect], split: str, redraw: int = 0, clip: bool | None = None) -> float:
        """Gap between the measured and the simulated frames of ``split`` (screen, fit, heldout);
        on the calibration splits not clipped at 0, so fits can still tell near-perfect values apart.
        With the sensor family, plus the paired-beam range term and per-channel shift terms (:meth:`paired_terms`).
        ``redraw`` > 0: the simulation's random processes drawn again (the scenario's seed + ``redraw``).
        ``clip``: clip at 0 (default: on the held-out split only)."""
        indices, keep = self._splits()[split], self.keep(split)
        clip = split == "heldout" if clip is None else clip
        frames = self.resim.frames(effects, indices, redraw=redraw)
        value = gap_value(self._measured[split], self.resim.signature(effects, indices, keep, frames), clip=clip)
        if "sensor" not in self.families:
            return value
        return value + self.paired_terms(effects, indices, frames, keep, clip, redraw)

    def paired_terms(self, effects: list[Effect], indices: list[int], frames: list[np.ndarray],
                     keep: Callable[[np.ndarray], np.ndarray] | None, clip: bool, redraw: int = 0) -> float:  # fmt: skip
        """How the recorded returns depart from the simulated ones beam by beam, beyond what the simulator's own
        noise gives, from :func:`~lidar_weather_sim.gap.signatures.paired_residuals` of recorded minus simulated
        and, as the reference, of a second, independent simulation of the same frames minus the first (costs a
        second simulation of the frames). The sum of:

        - range: the systematic Bray-Curtis (:func:`systematic_bray_curtis`) between the two range-residual
          histograms; equal when the simulation has the recording's range bias (a shift) and noise (the width);
        - each channel's own intensity, range and elevation shifts
          (:func:`~lidar_weather_sim.gap.signatures.channel_shift_term`); zero when the simulation has every
          channel's gain and elevation (a weak channel that keeps its returns, or one 0.1 deg off on a
          128-channel unit, shows nowhere else).

        Sensor-frame points (those ``keep`` selects), the recorded poses common to both sides."""
        columns, channels = self.resim.world.profile.scan.columns, self.resim.channels
        recorded = [self.resim.recording.frames[i].points for i in sorted(indices)]
        again = self.resim.frames(effects, indices, redraw=redraw + REDRAW_SEED_OFFSET)
        if keep is not None:
            recorded, frames, again = ([p[keep(p)] for p in part] for part in (recorded, frames, again))
        measured = [paired_residuals(r, f, columns, channels) for r, f in zip(recorded, frames)]
        simulated = [paired_residuals(a, f, columns, channels) for a, f in zip(again, frames)]
        n = len(indices)
        ranges = systematic_bray_curtis(sum(m[0] for m in measured), n, sum(s[0] for s in simulated), n, clip)
        shifts = sum(channel_shift_term(sum(m[k] for m in measured), sum(s[k] for s in simulated), scale)
                     for k, scale in enumerate((INTENSITY_SHIFT_SCALE_BYTES, RANGE_SHIFT_SCALE_M,
                                                ELEVATION_SHIFT_SCALE_DEG), start=1))  # fmt: skip
        return ranges + shifts

    def _objective(self, accepted: list[Effect], candidate: Effect, split: str, cache: dict[float, float]):
        """The gap of ``accepted`` + ``candidate`` at search-space value x, memoised in ``cache``."""

        def objective(x: float) -> float:
            key = round(float(x), 6)
            if key not in cache:
                cache[key] = self.gap(accepted + [self._value(candidate, x)], split)
            return cache[key]

        return objective

    def _value(self, effect: Effect, x: float) -> Effect:
        """``effect`` at search-space value ``x`` (log of the value where the effect spans decades)."""
        spec = effect.spec
        lo, hi = spec.bounds
        return effect.with_value(float(np.clip(np.exp(x), lo, hi)) if spec.log_search else float(x))

    def _grid(self, effect: Effect) -> np.ndarray:
        xs = search_grid(effect.spec, self.grid)
        return np.log(xs) if effect.spec.log_search else xs

    def gaps(self, jobs: list[tuple]) -> list[float]:
        """:meth:`gap` of every (effects, split[, redraw]), on the engine's workers when there is one."""
        if self.engine is None:
            return [self.gap(*job) for job in jobs]
        return self._remote(remote_gap, jobs)

    def _remote(self, task, jobs: list) -> list:
        out = [None] * len(jobs)
        for outcome in self.engine.map(partial(task, self.source), jobs):
            if outcome.error:
                raise RuntimeError(f"gap search: an evaluation failed on a worker: {outcome.error}")
            out[outcome.index], casts = outcome.result
            self.resim.casts += casts
        return out

    def fit(self, accepted: list[Effect], candidate: Effect, xs: np.ndarray, k: int,
            cache: dict[float, float] | None = None) -> tuple[Effect, float, int]:  # fmt: skip
        """Brent refinement on the calibration frames between the grid neighbours of ``xs[k]``
        (``cache``: calibration gaps already known, by search-space value); a categorical effect is
        tried with every choice instead."""
        spec = candidate.spec
        cache = {} if cache is None else cache
        objective = self._objective(accepted, candidate, "fit", cache)
        if spec.categorical:
            for x in search_grid(spec, len(spec.choices)):
                objective(x)
            x = min(cache, key=cache.get)
            return self._value(candidate, x), cache[x], len(cache)
        objective(xs[k])
        lo, hi = xs[max(k - 1, 0)], xs[min(k + 1, len(xs) - 1)]
        tol = 0.01 if spec.log_search else 0.002 * (spec.bounds[1] - spec.bounds[0])
        minimize_scalar(objective, bounds=(lo, hi), method="bounded", options={"xatol": tol, "maxiter": 10})
        x = min(cache, key=cache.get)
        return self._value(candidate, x), cache[x], len(cache)

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
        alone may have absorbed part of another (dirt dims the spray behind it) - ``passes`` times. An evident
        effect is what the data shows (:meth:`evident`) and stays as it is: refitted, a recorded return mode
        would go to whichever mode fits the calibration frames a hair better."""
        effects = list(effects)
        for _ in range(passes):
            for i, effect in enumerate(effects):
                if self.evident(effect):
                    continue
                others = effects[:i] + effects[i + 1 :]
                current = np.log(effect.value) if effect.spec.log_search else effect.value
                xs = np.unique(np.append(self._grid(effect), current))
                row = self.gaps([(others + [self._value(effect, x)], "fit") for x in xs])
                cache = {round(float(x), 6): g for x, g in zip(xs, row)}
                k = int(np.argmin(row))
                effects[i] = self.fit(others, effect, xs, k, cache)[0]
        return effects

    def pair_start(self, effects: list[Effect]) -> list[Effect] | None:
        """The effects with the two weather effects of the best point of every pair's two-dimensional grid on the
        screening frames, the others as they are; None when no grid point screens better than ``effects``
        (or fewer than two weather effects are fitted: the sensor family's keep their values, as in
        :meth:`joint_round`)."""
        free = [i for i, e in enumerate(effects)
                if e.spec.family == "weather" and not e.spec.categorical and not self.evident(e)]  # fmt: skip
        jobs = []
        for a, i in enumerate(free):
            for j in free[a + 1 :]:
                for x in self._grid(effects[i]):
                    for y in self._grid(effects[j]):
                        trial = list(effects)
                        trial[i], trial[j] = self._value(effects[i], x), self._value(effects[j], y)
                        jobs.append(trial)
        if not jobs:
            return None
        row = self.gaps([(trial, "screen") for trial in jobs] + [(list(effects), "screen")])
        k = int(np.argmin(row[:-1]))
        return jobs[k] if row[k] < row[-1] else None

    def run_round(self, accepted: list[Effect], excluded: list[Effect] = ()) -> list[Candidate]:
        """Screen every candidate (but those ``excluded``) on its grid, refine the best ``refine`` (with the sensor
        family the most promising: :func:`promise`), score all on the held-out frames; the evaluations of each
        step are independent (and run on the engine's workers when there is one)."""
        options = [c for c, _ in self.options(accepted, excluded)]
        grids = [self._grid(c) for c in options]
        gaps = iter(self.gaps([(accepted + [self._value(c, x)], "screen") for c, xs in zip(options, grids) for x in xs]))
        screened = []
        for c, xs in zip(options, grids):
            row = [next(gaps) for _ in xs]
            k = int(np.argmin(row))
            rank = promise(xs, row, k) if "sensor" in self.families and not c.spec.categorical else row[k]
            screened.append((c, self._value(c, xs[k]), row[k], xs, k, rank))
        order = sorted(range(len(screened)), key=lambda i: screened[i][5])
        best = [(accepted, screened[i][0], screened[i][3], screened[i][4]) for i in order[: self.refine]]
        fits = [self.fit(*job) for job in best] if self.engine is None else self._remote(remote_fit, best)
        fitted = [(fits[rank] if rank < len(fits) else (screened[i][1], screened[i][2], 0)) for rank, i in enumerate(order)]
        heldout = self.gaps([(accepted + [effect], "heldout") for effect, _, _ in fitted])
        out = []
        for (effect, gap, n), held in zip(fitted, heldout):
            out.append(Candidate(effect, gap, held, self.grid + n))
            self.progress(f"{effect.label()}: held-out gap {held:.4f}")
        return out

    def joint_round(self, accepted: list[Effect], excluded: list[Effect] = ()) -> list[Candidate]:
        """:meth:`run_round` with the accepted effects free, for when no candidate qualifies with them fixed: an
        effect accepted alone may have absorbed part of the one still missing, and next to it that one no longer
        helps (a dirt of 0.36 accepted for a sun of 400 W/m^2 behind a dirt of 0.62: both dim the returns). Each
        candidate's grid values are screened with each accepted weather effect in turn on its whole grid, the
        others as accepted (with one accepted effect: the full two-dimensional grid; the sensor family's effects
        keep their values: read off the data, or on 7-value grids that would make the round 8 times a plain
        one); the best ``refine`` (and every one that replaces an accepted effect, :func:`refined_ranks`) are refined
        from there with the accepted effects at their screened values, and every one is scored on the held-out
        frames with them. A candidate that conflicts with one accepted effect is tried in
        its place (:meth:`options`): the first of two effects that cannot go together may have been accepted for
        the other (snow at 0.7 mm/h for rain at 21 mm/h behind a dirty cover), which then can no longer be tried."""
        sets = []  # per candidate: (it, its grid, [(the accepted effects of a job, its grid index in that job)], swap)
        for c, base in self.options(accepted, excluded, swaps=True):
            xs = self._grid(c)
            variants = [(list(base), k) for k in range(len(xs))]
            for i, e in enumerate(base):
                if e.spec.family == "weather" and not e.spec.categorical:
                    variants += [(base[:i] + [self._value(e, y)] + base[i + 1 :], k)
                                 for y in self._grid(e) for k in range(len(xs))]  # fmt: skip
            if len(variants) > len(xs) or len(base) < len(accepted):
                sets.append((c, xs, variants, len(base) < len(accepted)))
        gaps = iter(self.gaps([(others + [self._value(c, xs[k])], "screen")
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
        fits = [self.fit(*job) for job in jobs] if self.engine is None else self._remote(remote_fit, jobs)
        fits = dict(zip(chosen, fits))
        fitted = [(others, *(fits[r] if r in fits else (self._value(c, xs[k]), gap, 0)), n)
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
        fitted = [e for e in accepted if e.spec.family == "weather" and not e.spec.categorical and not self.evident(e)]
        if len(fitted) < 2 or accepted[-1] is not fitted[-1]:
            return []
        self.progress(f"without {accepted[-1].label()}:")
        return self.joint_round(accepted[:-1], [*excluded, accepted[-1]])

    def options(self, accepted: list[Effect], excluded: list[Effect] = (),
                swaps: bool = False) -> list[tuple[Effect, list[Effect]]]:  # fmt: skip
        """The candidate effects of a round, each with the accepted effects it goes with: every effect of the
        searched families and those read off the data, but those accepted or ``excluded``, a recorded return
        mode, and those conflicting with the accepted; with ``swaps``, one that conflicts with a single accepted
        effect (not evident) goes with the others instead."""
        read_off = [c for c in self.data_candidates if c.spec.from_data]  # the others: on the rounds' grids anyway
        known = ["sensor.return_mode"] if self.recorded_mode is not None else []  # recorded: not searched
        out = []
        for c in candidate_effects(self.resim, self.families) + read_off:
            if any(_same(c, a) for a in [*accepted, *excluded]) or c.name in known:
                continue
            base = list(accepted) if conflicts(accepted + [c]) is None else None
            if base is None and swaps:
                kept = [a for a in accepted if conflicts([a, c]) is None]
                gone = [a for a in accepted if conflicts([a, c]) is not None]
                if len(gone) == 1 and not self.evident(gone[0]) and conflicts(kept + [c]) is None:
                    base = kept
            if base is not None:
                out.append((c, base))
        return out

    def run(self) -> Diagnosis:
        before = self.gap([], "heldout")
        diag = Diagnosis(before, before, fit_indices=self.fit_idx, heldout_indices=self.held_idx)
        current, accepted = before, []
        self.progress(f"gap before: {before:.4f}")
        current, accepted = self.data_round(diag, current)
        unconfirmed: list[Effect] = []  # not confirmed on the redraws: left out until another effect is accepted
        while True:
            fitted = self.run_round(accepted, unconfirmed)
            if not fitted:
                break
            diag.rounds.append(fitted)
            best = min(fitted, key=lambda c: c.heldout_gap)
            required = self.required(current)
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
            if not self.confirmed(accepted, refitted):  # its gain was the held-out draw's noise: try the others
                unconfirmed.append(best.effect)
                diag.rejected = fitted
                continue
            unconfirmed = []
            accepted = refitted
            best = Candidate(accepted[-1], best.fit_gap, heldout, best.evaluations)
            kept = [(c, g) for c, g in diag.accepted if any(_same(c.effect, e) for e in accepted)]  # but a swap's
            diag.accepted = [(Candidate(e, c.fit_gap, c.heldout_gap, c.evaluations), g)
                             for e, (c, g) in zip(accepted, kept)]  # fmt: skip
            diag.accepted.append((best, current))
            current = best.heldout_gap
            diag.rejected = [c for c in fitted if c is not best]
        diag.gap_after = self.prune(diag, current)
        return diag

    def worth(self, effect: Effect, held: float, current: float) -> bool:
        """Whether ``effect`` earns its place: the held-out gap with it (``held``) meets :meth:`required` of the
        gap without it (``current``). An evident effect (a channel silent in every calibration frame where the
        model returns on it, or the return mode the recording's codes name) needs only not to make the gap worse:
        two of 128 channels move the gap by about the margin, less than what the counts themselves prove, and
        ``dual`` on a two-echo sensor changes no point."""
        return held <= (current if self.evident(effect) else self.required(current))

    def evident_on_redraws(self, effect: Effect, accepted: list[Effect]) -> bool:
        """Whether an evident ``effect`` (see :meth:`worth`) does not make the held-out gap worse on the mean over
        the redraws (:meth:`redrawn`): with no margin to win, one held-out draw's noise (about 0.003) decides
        otherwise. False for other effects and without the sensor family."""
        if not self.evident(effect) or "sensor" not in self.families:
            return False
        with_it, without = self.redrawn([accepted + [effect], accepted])
        self.progress(f"{effect.label()}: mean over redraws {with_it:.4f} with it, {without:.4f} without")
        return with_it <= without

    def required(self, current: float) -> float:
        """The held-out gap an effect set must reach to beat one at ``current``: ``min_gain`` and ``min_abs_gain``."""
        return min(current * (1.0 - self.min_gain), current - self.min_abs_gain)

    def redrawn(self, effect_sets: list[list[Effect]]) -> list[float]:
        """The held-out gap of each effect set, averaged over the independent redraws of
        :data:`CONFIRM_SEED_OFFSETS` (the same redraws for every set)."""
        jobs = [(effects, "heldout", offset) for effects in effect_sets for offset in CONFIRM_SEED_OFFSETS]
        values = np.array(self.gaps(jobs)).reshape(len(effect_sets), len(CONFIRM_SEED_OFFSETS))
        return values.mean(axis=1).tolist()

    def confirmed(self, before: list[Effect], after: list[Effect]) -> bool:
        """Whether ``after`` still beats ``before`` by the margin on the mean over independent redraws of the
        held-out re-simulation (:meth:`redrawn`). Sensor family only (module doc, step 4); always true for the
        others."""
        if "sensor" not in self.families:
            return True
        was, now = self.redrawn([before, after])
        verdict = now <= self.required(was)
        self.progress(f"on independent redraws: held-out gap {was:.4f} -> {now:.4f}: "
                      f"{'confirmed' if verdict else 'not confirmed, rejected'}")  # fmt: skip
        return verdict

    def data_round(self, diag: Diagnosis, current: float) -> tuple[float, list[Effect]]:
        """Step 3's first trial of the effects read off the data, in turn, each accepted under the rule of
        step 4 on the held-out frames; returns the held-out gap and the effects accepted."""
        accepted: list[Effect] = []
        tried = []
        for effect in self.data_candidates:
            held = self.gap(accepted + [effect], "heldout")
            self.progress(f"{effect.label()} (read off the recording): held-out gap {held:.4f}")
            candidate = Candidate(effect, float("nan"), held, 1)
            tried.append(candidate)
            if self.worth(effect, held, current) or self.evident_on_redraws(effect, accepted):
                diag.accepted.append((candidate, current))
                accepted.append(effect)
                current = held
        if tried:
            diag.rounds.append(tried)
        return current, accepted

    def prune(self, diag: Diagnosis, current: float) -> float:
        """Backward elimination: an accepted effect stays only if the held-out gap without it (the
        others as fitted) is worse by the margin a new effect must win (``min_gain`` and
        ``min_abs_gain``); else it is dropped, reported as rejected, and the rest refitted. A small
        effect accepted early can become redundant once a later one explains the same residual.
        Returns the held-out gap of what stays."""
        while len(diag.accepted) > 1:
            effects = diag.effects
            subsets = [effects[:i] + effects[i + 1 :] for i in range(len(effects))]
            without, now, where = self.gaps([(subset, "heldout") for subset in subsets]), current, "held-out"
            worth = [self.worth(e, now, w) for e, w in zip(effects, without)]
            single = [w or self.evident(e) for e, w in zip(effects, worth)]  # an evident effect: on the redraws
            if "sensor" in self.families and all(single):  # and on the redraws, as an effect is accepted
                now, *without = self.redrawn([effects] + subsets)
                where = f"mean over redraws ({now:.4f} with it),"
                worth = [self.worth(e, now, w) for e, w in zip(effects, without)]
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


def refined_ranks(swaps: list[bool], refine: int) -> list[int]:
    """Which candidates of a joint round, ranked by their screened gap (``swaps``: each one replaces an accepted
    effect), are refined: the best ``refine``, and every replacement. A replacement is screened on its coarse grid
    against the refitted effect it replaces, so it ranks behind candidates that change little (draw case 24: rain
    on its 5 values in place of a refitted snow, behind a spray at its floor and water in place of the dirt);
    refined, it may win. Conflicts are few (rain or snow, dirt or water), so are replacements."""
    return list(range(min(refine, len(swaps)))) + [r for r, swap in enumerate(swaps) if swap and r >= refine]


def promise(xs: np.ndarray, row: list[float], k: int) -> float:
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


def _same(a: Effect, b: Effect) -> bool:
    """The same effect (and the same emitter for spray)."""
    return a.name == b.name and a.params.get("actor") == b.params.get("actor")
