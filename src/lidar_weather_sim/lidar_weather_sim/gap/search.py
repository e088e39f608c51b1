"""``lidar-weather-sim gap``: measure the reality gap of a recording, name the missing effects, fit them.

1. The recording's frames are split by index: even frames calibrate, odd frames are held out (each layer's
   frames so on a sensor whose scans alternate their layers; or as a twin's split.yaml says,
   :mod:`lidar_weather_sim.gap.split`: its frames, or for a sector split the same frames with the calibration
   and held-out azimuth sectors' points). Up to
   ``fit_frames`` evenly spaced calibration frames are used for fitting and up to ``heldout_frames`` held-out
   frames for every decision (:func:`lidar_weather_sim.gap.split.split_frames`).
2. The gap is :func:`lidar_weather_sim.gap.signatures.gap_value` between the measured frames
   and the same frames re-simulated from the recorded poses (:mod:`lidar_weather_sim.gap.evaluation`,
   :mod:`lidar_weather_sim.gap.signatures`).
3. Read-off round (:meth:`GapSearch.read_off_round`). With the sensor family,
   the effects read off the recording (:mod:`lidar_weather_sim.gap.read_off`: dead and weak channels,
   elevation offsets, the beams' origin at the value the points' elevations show, the near-field ghost at the
   rate its cover-zone count shows) are tried first, each in turn on the held-out frames under the
   rule of step 4: they are what the data shows, not fits, and a fitted effect accepted before them can
   absorb their residual at a wrong value (a wide range noise smearing an offset channel's ranges), after
   which they no longer earn the margin. One that does not earn it is tried again in the screening rounds.
   Dead channels are proven by the data (:meth:`~lidar_weather_sim.gap.evaluation.GapEvaluator.earns_margin`):
   accepted and kept unless they make the gap worse. So is the return mode the points' ``return_type`` codes
   name (:mod:`lidar_weather_sim.gap.read_off`): a recording that says its mode is not searched for one
   (two modes can give the same points).
   Screening round (:meth:`GapSearch.screen_round`): every candidate effect
   the model knows (:data:`lidar_weather_sim.scenario.effects.EFFECTS`; spray once per vehicle of the
   scenario) that does not conflict with those already accepted is screened: its main parameter is tried on a
   grid of ``grid`` values (5; 7 with the sensor family: :data:`~lidar_weather_sim.gap.evaluation.SENSOR_GRID`)
   over its bounds (log-spaced where the effect spans decades) on ``screen_frames`` of the
   calibration frames. The ``refine`` (3) candidates that screen best are then fitted on all
   calibration frames by bounded Brent minimisation (scipy) between the grid neighbours of
   their best value (:meth:`~lidar_weather_sim.gap.evaluation.GapEvaluator.fit`). Every candidate is scored on the held-out frames
   at its best value.
4. Acceptance (:mod:`lidar_weather_sim.gap.evaluation`). The candidate with the lowest held-out gap is accepted
   if it shrinks the current held-out gap by at least ``min_gain`` (10 %) and by at least ``min_abs_gain``
   (0.002: below that the change is at the level of what re-drawing the measurement's noise
   moves the gap, e.g. 0.004-0.008 for the nuisance of ``make-measured``); the accepted
   effects are then refitted together, and the new effect is kept only if the refitted set
   still meets that rule on the held-out frames (otherwise its gain was fitting noise that
   the joint fit takes back). With the sensor family it must also meet the rule on the mean
   over independent redraws of every random process of the held-out re-simulation
   (:meth:`~lidar_weather_sim.gap.evaluation.GapEvaluator.confirmed_on_redraws`): the best of a dozen
   candidates on one held-out draw is chosen by that draw's noise too, and a sensor effect at the edge of its
   range (a 3 mm range noise on a unit's 1.5 cm) can win by that noise alone; the round is then run again
   without it (until another effect is accepted), as it may have hidden the right effect from
   the refinement. When no candidate qualifies next to the accepted effects as fitted, the round is run
   again with them free (:meth:`GapSearch.joint_round`): an effect accepted
   alone may have absorbed part of the missing one (dirt fitted at 0.36 for sun behind a dirt of 0.62), and
   next to it the missing one no longer helps. When that does not qualify either, it is run once more without
   the last accepted weather effect (:meth:`GapSearch.swap_round`), whose
   place a candidate takes if it beats the gap with it by the margin (its best refitted with the others first:
   a fog and a dirt trade off along a valley the grids miss): the first effect may have imitated the
   missing one and the last fitted the leftover.
   Rounds repeat until no candidate qualifies. The other candidates of the
   last round are reported as rejected with their held-out gap. After the first round no round is run once the
   held-out gap is below ``min_abs_gain``: a held-out gap (clipped at 0) cannot beat it, so nothing would be
   accepted (the first round always runs: a clear recording's report lists every candidate with its gap).
5. Pruning round (:meth:`GapSearch.prune_round`, backward elimination): each accepted effect must still be
   worth that margin with all the others in place; one that is not (a weak effect accepted early,
   made redundant by a later one) is dropped and the rest refitted.
6. Giving way (:meth:`GapSearch.give_way_round`): each accepted weather effect is compared with each effect that
   cannot go with it fitted in its place beside the others as they ended (:meth:`GapSearch.in_place_of`: rain for
   snow, water for dirt), or that is its more general form (dirt or water on the cover for a wet road); the best
   that beats the search's result by the margin on this draw and on each redraw takes its place.
7. Judgement (:meth:`GapSearch.judge`, :mod:`lidar_weather_sim.gap.unexplained`): on the held-out frames, each
   accepted weather effect is named only when it removes the residual of the zones that are its physics (not only
   the total gap) and when it beat every other effect of the round it won by the margin a new effect must win
   (:func:`rivals`), and every effect of step 6 (:meth:`GapSearch.conflict_rivals`); a difference under the
   margin's absolute floor tells them apart when it holds on each redraw (:meth:`GapSearch.told_apart`). The
   zones whose residual the named effects leave above the counting noise are reported as unexplained, with the
   shape of the residual. The search's fit (the patched scenario) is unchanged by the judgement.

Cost: the budgets do not grow with the recording, so a diagnosis casts about
``(candidates x (grid x screen_frames + heldout_frames) + refine x 10 x fit_frames)``
frames per round, whatever the length of the recording; a round with the accepted effects free screens
``grid x (1 + grid x free effects)`` values per candidate instead of ``grid``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from lidar_weather_sim.gap.evaluation import GapEvaluator, effects_key
from lidar_weather_sim.gap.signatures import GapResimulator
from lidar_weather_sim.gap.unexplained import Judgement, judge_effects
from lidar_weather_sim.scenario.effects import EFFECTS, Effect, conflicts, spray_candidates



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
    """The search's result: the held-out gap before and after, the accepted effects (each with the held-out gap
    before it), those rejected, every round's candidates and the frames used."""

    gap_before: float
    gap_after: float
    accepted: list[tuple[Candidate, float]] = field(default_factory=list)  # (candidate, gap before it)
    rejected: list[Candidate] = field(default_factory=list)
    rounds: list[list[Candidate]] = field(default_factory=list)
    fit_indices: list[int] = field(default_factory=list)
    heldout_indices: list[int] = field(default_factory=list)
    #: per effect set (:func:`~lidar_weather_sim.gap.evaluation.effects_key`), :meth:`GapSearch.in_place_of`
    in_place: dict[tuple, list] = field(default_factory=dict)

    @property
    def effects(self) -> list[Effect]:
        return [c.effect for c, _ in self.accepted]


#: the fog is tried at these backscatter gains (region ``atmosphere``'s ``fog_backscatter_gain``): its loss is
#: Beer-Lambert on every sensor, but how much of its backscatter a unit turns into soft echoes is its own (pulse
#: discrimination, near-range gain, blanking, overlap; sized by no datum but scala's), and a fog whose soft echoes the
#: model puts on every beam where the unit shows none scored worse than no fog at all (draw case 0, its 8 frames:
#: 0.536 against 0.130); at 0.15 the model's echoes are gone out to a few hundred metres of visual range and thinned
#: in denser fog
FOG_GAINS = (1.0, 0.15, 0.0)
#: dirt on the cover is tried at these return gains (region ``cover``'s ``texture_return_gain``): the thesis' samples
#: put multipath returns at 0-0.5 m at a rate growing with the dirt, but whether a unit reports them (or blanks its
#: cover zone) is its own; a unit without them lost the dirt's name to the fog in front of it (draw case 5)
DIRT_GAINS = (1.0, 0.0)
#: and in these two kinds: as the thesis' samples, in patches (region ``cover``'s texture, its spread of transmission
#: over the window) with the texture's forward share (the thesis measured forward scattering on its two heaviest
#: samples only, 3 and 5, "the composition and type of dirt has a larger influence", paper 1, and a generic dirt
#: takes their share by opacity: 0.35 below a transmission of 0.66); and as a uniform film that only absorbs
#: (``forward_share`` 0: it widens no beam; ``texture_contrast`` 0: every direction loses alike). With the share, the
#: wider beam keeps far returns the absorbing dirt of the same transmission loses: a fixed generator's uniform dirt
#: of 0.606 on scala4 (8 frames) scored 0.068 at its own transmission against 0.057 for a fog of 150 m, and 0.024
#: without it. With the patches, the directions behind the darker ones lose more than the rest: behind a fog of
#: 40.4 m, a fixed generator's uniform dirt of 0.708 (draw case 25, 24 frames) scored 0.018 at the hidden pair
#: without the share but in patches, against 0.010 for a fog of 34.8 m behind a dirt of 0.956 that the search named;
#: as a uniform film, 0.005
DIRT_KINDS: tuple[dict[str, float], ...] = ({}, {"forward": 0.0, "contrast": 0.0})
#: effects compared at the end also with the more general ones fitted in their place (besides those that cannot go
#: with them, :meth:`GapSearch.conflict_rivals`): a wet road darkens the up-facing surfaces alone, dirt or water on
#: the cover every return; where a fog hides the vehicles the road is all that is left to tell them apart, and a
#: fog of 51.4 m behind a dirt of 0.889 was named as a fog of 47.9 m and a wet road of 0.2 mm (OS1 draw case 15)
GENERAL_RIVALS = {"atmosphere.road_wet": ("cover.dirt", "cover.water")}
#: the variants of an effect the search screens (each its extra parameters): the fog at each backscatter gain, the
#: dirt at each return gain in each kind; an effect not listed has one
VARIANTS: dict[str, tuple[dict[str, float], ...]] = {
    "atmosphere.fog": tuple({"gain": g} if g != 1.0 else {} for g in FOG_GAINS),
    "cover.dirt": tuple({**({"gain": g} if g != 1.0 else {}), **kind} for kind in DIRT_KINDS for g in DIRT_GAINS),
}


def same_effect(a: Effect, b: Effect) -> bool:
    """The same effect (and the same emitter for spray)."""
    return a.name == b.name and a.params.get("actor") == b.params.get("actor")


def replaces(effect: Effect, other: Effect) -> bool:
    """Whether ``other`` is one of the effects that may stand in ``effect``'s place at the end: one that cannot go with
    it (rain for snow, water on the cover for dirt) or its more general form (:data:`GENERAL_RIVALS`)."""
    return conflicts([effect, other]) is not None or other.name in GENERAL_RIVALS.get(effect.name, ())


def same_variant(a: Effect, b: Effect) -> bool:
    """The same effect in the same variant: every parameter but the main one alike (the fog's gain, the dirt's kind)."""
    main = a.spec.main
    return a.name == b.name and {k: v for k, v in a.params.items() if k != main} == {
        k: v for k, v in b.params.items() if k != main}


def rivals(diag: Diagnosis, gap_to_beat: Callable[[float], float]) -> list[list[Candidate]]:
    """Per accepted effect of ``diag``, the candidates of other effects in the last round it won that it does not beat
    by the margin a new effect must win: its held-out gap above ``gap_to_beat`` of theirs. By the search's own
    standard the data did not tell them apart. Not one that cannot go with the other accepted effects as they ended
    (a snow or a rain beside the rain the search ended with): it cannot stand in its place (seeded draw case 6, rain
    20.9 mm/h behind a dirt of 0.726: the dirt won the first round by 8 % over a snow and a rain, and was refused for
    them although the search then found the rain). The judgement fits each again in the effect's place at the end
    (:meth:`GapSearch.in_place_of`)."""
    out = []
    effects = diag.effects
    for i, (candidate, _) in enumerate(diag.accepted):
        others = effects[:i] + effects[i + 1 :]
        name = candidate.effect.name
        # the rounds it won: their best is this effect (the same emitter, for spray)
        won = [r for r in diag.rounds if r and same_effect(min(r, key=lambda c: c.heldout_gap).effect,
                                                           candidate.effect)]  # fmt: skip
        best = min(won[-1], key=lambda c: c.heldout_gap) if won else None
        out.append([] if best is None else [c for c in won[-1] if c.effect.name != name
                                            and best.heldout_gap > gap_to_beat(c.heldout_gap)
                                            and conflicts(others + [c.effect]) is None])  # fmt: skip
    return out


def candidate_effects(resim: GapResimulator, families: tuple[str, ...] = ("weather",)) -> list[Effect]:
    """One untuned effect per name of ``families`` (the spray once per vehicle, the fog and the dirt once per variant
    of :data:`VARIANTS`), at the middle of its bounds;
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
        elif name in VARIANTS:
            out += [Effect(name, {spec.main: mid, **extra}) for extra in VARIANTS[name]]
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


def refined_variants(ranked: list[Effect], refine: int) -> list[int]:
    """Which of the screened candidates ``ranked`` (best first) a plain round refines: the best ``refine`` effects,
    each with all its variants (the fog at each of its backscatter gains, the dirt at each return gain in each kind,
    in their rank order). A variant's screen on a coarse grid and a few frames does not rank the gains: draw case 5 (fog
    200 m without soft echoes behind dirt) screened its fog at gain 0 behind gain 0.15 and a dirt, which took the
    two refinements, and the fog was accepted at gain 0.15 with soft echoes the recording does not have."""
    top: list[Effect] = []
    for e in ranked:
        if len(top) < refine and not any(same_effect(e, t) for t in top):
            top.append(e)
    return [r for r, e in enumerate(ranked) if any(same_effect(e, t) for t in top)]


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


class GapSearch(GapEvaluator):
    """The diagnosis of the module doc over one recording and scenario: :meth:`run` drives the rounds
    (:meth:`read_off_round`, :meth:`screen_round`, :meth:`joint_round`, :meth:`swap_round`) and ends with
    :meth:`prune_round`; the gaps, fits and the acceptance rule they use are :class:`GapEvaluator`'s."""

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
        family the most promising: :func:`reachable_gap`) with every variant of theirs (:func:`refined_variants`),
        score all on the held-out frames; the evaluations of
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
        refined = refined_variants([screened[i][0] for i in order], self.refine)
        order = [order[r] for r in refined] + [i for r, i in enumerate(order) if r not in refined]
        best = [(accepted, screened[i][0], screened[i][3], screened[i][4]) for i in order[: len(refined)]]
        fits = self.fits(best)
        fitted = [(fits[rank] if rank < len(fits) else (screened[i][1], screened[i][2], 0)) for rank, i in enumerate(order)]
        heldout = self.gaps([(accepted + [effect], "heldout") for effect, _, _ in fitted])
        out = []
        for (effect, gap, n), held in zip(fitted, heldout):
            out.append(Candidate(effect, gap, held, self.grid + n, tuple(accepted)))
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
        sets = []  # per candidate: (it, its grid, [(the accepted effects of a job, its grid index, the one moved)], swap)
        for c, base in self.round_candidates(accepted, excluded, swaps=True):
            xs = self.grid_of(c)
            variants = [(list(base), k, None) for k in range(len(xs))]
            for i, e in enumerate(base):
                if e.spec.family == "weather" and not e.spec.categorical:
                    variants += [(base[:i] + [self.at_value(e, y)] + base[i + 1 :], k, (i, j))
                                 for j, y in enumerate(self.grid_of(e)) for k in range(len(xs))]  # fmt: skip
            if len(variants) > len(xs) or len(base) < len(accepted):
                sets.append((c, xs, variants, len(base) < len(accepted)))
        gaps = iter(self.gaps([(others + [self.at_value(c, xs[k])], "screen")
                               for c, xs, variants, _ in sets for others, k, _ in variants]))  # fmt: skip
        screened = []
        for c, xs, variants, swap in sets:
            row = [next(gaps) for _ in variants]
            j = int(np.argmin(row))
            others, k, moved = variants[j]
            screened.append((c, others, xs, k, row[j], len(row), swap, moved))
        screened.sort(key=lambda s: s[4])
        chosen = refined_ranks([s[6] for s in screened], self.refine)
        jobs = [(others, c, xs, k) for c, others, xs, k, *_ in (screened[r] for r in chosen)]
        fits = dict(zip(chosen, self.fits(jobs)))
        refined = self.polish_moved(screened, fits)  # rank -> (effect, fit gap, evaluations, accepted as polished)
        fitted = []
        for r, (c, others, xs, k, gap, n, *_) in enumerate(screened):
            effect, fit_gap, evaluations, others = refined.get(r, (self.at_value(c, xs[k]), gap, 0, others))
            fitted.append((others, effect, fit_gap, evaluations, n))
        heldout = self.gaps([(others + [effect], "heldout") for others, effect, _, _, _ in fitted])
        out = []
        for (others, effect, gap, n, screens), held in zip(fitted, heldout):
            out.append(Candidate(effect, gap, held, screens + n, tuple(others)))
            self.progress(f"{effect.label()} with {', '.join(e.label() for e in others) or 'nothing'} free: "
                          f"held-out gap {held:.4f}")  # fmt: skip
        return out

    def polish_moved(self, screened: list[tuple], fits: dict[int, tuple]) -> dict[int, tuple]:
        """The refined candidates of a joint round whose best screening point moved an accepted effect to another
        grid value: that effect refined too (Brent between its grid neighbours, the candidate at its fit), else it
        stays on a grid too coarse for two effects that trade off (fog of 200 m behind a dirt of 0.61 between the
        fog's grid values 122 and 348 m: with either, the dirt fitted no better than a sun beside a fog of 88 m).
        ``fits``: rank -> (candidate, fit gap, evaluations); returns rank -> (candidate, fit gap, evaluations, the
        accepted effects as polished)."""
        polish = [(r, *screened[r][7]) for r in fits if screened[r][7] is not None]
        jobs = [(screened[r][1][:i] + screened[r][1][i + 1 :] + [fits[r][0]], screened[r][1][i],
                 self.grid_of(screened[r][1][i]), j) for r, i, j in polish]  # fmt: skip
        out = {r: (*fit, screened[r][1]) for r, fit in fits.items()}
        for (r, i, _), (effect, gap, n) in zip(polish, self.fits(jobs) if jobs else []):
            others = screened[r][1]
            if gap <= fits[r][1]:
                out[r] = (fits[r][0], gap, fits[r][2] + n, others[:i] + [effect] + others[i + 1 :])
            self.progress(f"{fits[r][0].label()}: {others[i].label()} refined to {effect.label()}, fit gap {gap:.4f}")
        return out

    def swap_round(self, accepted: list[Effect], excluded: list[Effect] = ()) -> list[Candidate]:
        """:meth:`joint_round` without the last accepted effect (and not offering it), for when neither a plain nor a
        joint round qualifies and it is a fitted weather effect accepted after another: an effect accepted alone
        may have imitated the missing one, and the next one accepted beside it then fits what is left over (fog
        107 m behind a dirt of 0.66: fog at 594 m imitated the near field the dirt dims, then a sun of 126 W/m^2
        qualified, where fog and dirt together leave a quarter of their gap). A candidate of this round
        replaces that effect when it beats the gap with it by the margin; its best candidate is first refitted
        together with the others (:meth:`refit`). Empty when there is no such effect (one round with the others
        free costs about 6 plain rounds)."""
        fitted = [e for e in accepted
                  if e.spec.family == "weather" and not e.spec.categorical and not self.proven_by_data(e)]  # fmt: skip
        if len(fitted) < 2 or accepted[-1] is not fitted[-1]:
            return []
        self.progress(f"without {accepted[-1].label()}:")
        found = self.joint_round(accepted[:-1], [*excluded, accepted[-1]])
        if not found:
            return found
        # its best refitted together with the others: the joint round moves them on their grids only, and a dirt
        # that trades off with a fog along a narrow valley stays far from it (OS1 draw case 15: dirt 0.954 beside a
        # fog of 47.9 m, held-out gap 0.0246; refitted, fog 50.3 m and dirt 0.900, 0.0101; hidden: 51.4 m, 0.889)
        k = min(range(len(found)), key=lambda i: found[i].heldout_gap)
        best = found[k]
        *others, effect = self.refit(list(best.companions) + [best.effect])
        heldout = self.gap(others + [effect], "heldout")
        self.progress(f"{effect.label()} with {', '.join(e.label() for e in others) or 'nothing'} refitted: "
                      f"held-out gap {heldout:.4f}")  # fmt: skip
        if heldout < best.heldout_gap:
            found[k] = Candidate(effect, self.gap(others + [effect], "fit"), heldout, best.evaluations, tuple(others))
        return found

    def run(self) -> Diagnosis:
        before = self.gap([], "heldout")
        diag = Diagnosis(before, before, fit_indices=self.fit_idx, heldout_indices=self.held_idx)
        current, accepted = before, []
        self.progress(f"gap before: {before:.4f}")
        current, accepted = self.read_off_round(diag, current)
        unconfirmed: list[Effect] = []  # not confirmed on the redraws: left out until another effect is accepted
        screened = False
        while True:
            if screened and self.gap_to_beat(current) < 0:  # a held-out gap (clipped at 0) cannot beat it
                self.progress(f"held-out gap {current:.4f} is within the margin of 0: no other effect can earn a place")
                break
            fitted, screened = self.screen_round(accepted, unconfirmed), True
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
            diag.rejected = [c for c in fitted if c is not best]  # the round's others, until a next round is screened
            best = Candidate(accepted[-1], best.fit_gap, heldout, best.evaluations)
            kept = [(c, g) for c, g in diag.accepted if any(same_effect(c.effect, e) for e in accepted)]  # but a swap's
            diag.accepted = [(Candidate(e, c.fit_gap, c.heldout_gap, c.evaluations), g)
                             for e, (c, g) in zip(accepted, kept)]  # fmt: skip
            diag.accepted.append((best, current))
            current = best.heldout_gap
        diag.gap_after = self.prune_round(diag, current)
        self.give_way_round(diag)
        return diag

    def judge(self, diag: Diagnosis) -> Judgement:
        """The judgement after the search (:mod:`lidar_weather_sim.gap.unexplained`): which of ``diag``'s effects
        remove the residual of the zones that are their physics on the held-out frames (named), which do not
        (refused), and the zones left unexplained. Runs in this process (a few held-out re-simulations)."""
        measured = self._measured["heldout"]
        keep = self.point_mask("heldout")
        judgement = judge_effects(diag.effects, measured, lambda effects: self.resim.signature(effects, self.held_idx, keep),
                                  self._measured["fit"], twin=self.resim.is_twin,
                                  rivals=self.conflict_rivals(diag))  # fmt: skip
        for effect, reason in judgement.refused:
            self.progress(f"{effect.label()} not named: {reason}")
        for residual in judgement.unexplained:
            self.progress(f"unexplained: {residual.text()} ({residual.sigma:.1f} sigma)")
        return judgement

    def decisive(self, ours_gap: float, ours: list[Effect], theirs_gap: float, theirs: list[Effect]) -> bool:
        """Whether the effect set ``ours`` (held-out gap ``ours_gap``) beats ``theirs`` by ``min_gain`` on this draw,
        is above it on no redraw and beats it by ``min_gain`` on their mean
        (:meth:`~lidar_weather_sim.gap.evaluation.GapEvaluator.beats_on_redraws`)."""
        return ours_gap <= (1.0 - self.min_gain) * theirs_gap and self.beats_on_redraws(ours, theirs)

    def in_place_of(self, diag: Diagnosis) -> list[list[tuple[list[Effect], Candidate]]]:
        """Per accepted effect of ``diag``, the effects that cannot go with it (rain for snow, water on the cover for
        dirt), that are its more general form (:data:`GENERAL_RIVALS`: dirt or water on the cover for a wet road) or
        that it did not beat by the margin in the round it won (:func:`rivals`), each fitted in its place beside the
        other accepted effects as they ended (screened on its grid, refined by Brent; a general rival refitted with
        them, :meth:`refit_with_others`) and scored on the held-out frames: (the effect set it was scored with, its
        candidate). The round compared them with the others as they were then: seeded draw case 22's snow won its
        round at 0.267 mm/h by 0.0007 over a rain and the sun beside that snow by 8 % over a dirt; refitted together
        they are 1.133 mm/h and 339 W/m^2 at 0.0003, and in their places the rain and the dirt do not come near. Kept
        in ``diag`` per effect set: :meth:`give_way_round` and :meth:`conflict_rivals` ask for the same."""
        effects = diag.effects
        key = effects_key(effects)
        if key in diag.in_place:
            return diag.in_place[key]
        close = rivals(diag, self.gap_to_beat)
        options = []  # per accepted effect, its rivals (one batch of each step for all effects)
        for i, effect in enumerate(effects):
            others = effects[:i] + effects[i + 1 :]
            if effect.spec.family != "weather" or effect.spec.categorical or self.proven_by_data(effect):
                options.append([])
                continue
            found = [c for c in candidate_effects(self.resim, self.families) if c.name != effect.name
                     and replaces(effect, c) and conflicts(others + [c]) is None]  # fmt: skip
            options.append(found + [c.effect for c in close[i] if not any(same_variant(c.effect, o) for o in found)])
        beside = [effects[:i] + effects[i + 1 :] for i in range(len(effects))]
        grids = [[self.grid_of(c) for c in opts] for opts in options]
        gaps = iter(self.gaps([(beside[i] + [self.at_value(c, x)], "screen") for i, opts in enumerate(options)
                               for c, xs in zip(opts, grids[i]) for x in xs]))  # fmt: skip
        jobs = [(beside[i], c, xs, int(np.argmin([next(gaps) for _ in xs])))
                for i, opts in enumerate(options) for c, xs in zip(opts, grids[i])]  # fmt: skip
        fits = iter(self.fits(jobs))
        fitted = [[(beside[i], *next(fits)) for _ in opts] for i, opts in enumerate(options)]
        for i, effect in enumerate(effects):
            if effect.name in GENERAL_RIVALS and fitted[i]:
                fitted[i] = self.refit_with_others(fitted[i])
        held = iter(self.gaps([(companions + [f], "heldout") for rows in fitted for companions, f, _, _ in rows]))
        out = []
        for i, effect in enumerate(effects):
            found = [(companions + [f], Candidate(f, gap, next(held), n, None if companions is beside[i] else
                                                  tuple(companions)))
                     for companions, f, gap, n in fitted[i]]  # fmt: skip
            for _, c in found:
                refitted = f" with {', '.join(e.label() for e in c.companions)} refitted" if c.companions else ""
                self.progress(f"{c.effect.label()} in place of {effect.label()}{refitted}: held-out gap "
                              f"{c.heldout_gap:.4f}")  # fmt: skip
            out.append(found)
        diag.in_place[key] = out
        return out

    def conflict_rivals(self, diag: Diagnosis) -> list[list[Candidate]]:
        """Per accepted effect, those of :meth:`in_place_of` that do as well in its place: a rival if the search's
        result does not beat it by the margin a new effect must win (nor is :meth:`told_apart` from it). The round
        an effect won compares it with the others as they were then: snow at 0.38 mm/h beat rain at 9.3 by 0.004
        beside a dirt of 0.72 fitted alone, and once the dirt was refitted (0.757) the hidden rain of 10 mm/h
        scored 0.0008 where the named snow scored 0.0016."""
        return [[c for theirs, c in found if diag.gap_after > self.gap_to_beat(c.heldout_gap)
                 and not self.told_apart(diag.gap_after, diag.effects, c.heldout_gap, theirs)]
                for found in self.in_place_of(diag)]  # fmt: skip

    def give_way_round(self, diag: Diagnosis) -> None:
        """An accepted weather effect gives way to one of :meth:`in_place_of` that may stand in its place
        (:func:`replaces`; not a rival of its round) and beats the search's result: by
        ``min_gain`` on the held-out frames, and not above it on any redraw and by ``min_gain`` on their mean
        (:meth:`~lidar_weather_sim.gap.evaluation.GapEvaluator.beats_on_redraws`; one draw's 10 % is not enough:
        on session 50's fit of fixed-generator case 8 a snow of 0.069 mm/h in place of a rain of 0.95 scored 0.0644
        against 0.0716, on the redraws 0.0648-0.0684 against 0.0663-0.0700). The best such one takes its place in
        ``diag`` (the others as set for it), the effect is reported rejected. The round an effect won compared it
        with the others as they were then (issue 50's speed case: a snow of 0.34 mm/h won beside a dirt fitted alone;
        with the dirt as it ended, the hidden rain of 10 mm/h in its place scores 0.0002 against the snow's 0.0016)."""
        current = diag.gap_after
        qualified = sorted(((c.heldout_gap, i, theirs, c) for i, found in enumerate(self.in_place_of(diag))
                            for theirs, c in found if replaces(diag.effects[i], c.effect)),
                           key=lambda q: q[0])  # fmt: skip
        for _, i, theirs, c in qualified:
            if not self.decisive(c.heldout_gap, theirs, current, diag.effects):
                continue
            gone, before = diag.accepted[i]
            rest = diag.accepted[:i] + diag.accepted[i + 1 :]
            diag.accepted = [(Candidate(e, k.fit_gap, k.heldout_gap, k.evaluations), g)
                             for e, (k, g) in zip(theirs[:-1], rest)]  # fmt: skip
            diag.accepted.append((Candidate(c.effect, c.fit_gap, c.heldout_gap, c.evaluations), before))
            diag.rejected.append(Candidate(gone.effect, gone.fit_gap, current, gone.evaluations))
            diag.gap_after = c.heldout_gap
            self.progress(f"{gone.effect.label()} gives way to {c.effect.label()} fitted in its place: held-out gap "
                          f"{current:.4f} -> {c.heldout_gap:.4f}")  # fmt: skip
            return

    def told_apart(self, ours_gap: float, ours: list[Effect] | None, theirs_gap: float,
                   theirs: list[Effect] | None) -> bool:  # fmt: skip
        """Whether the effect set ``ours`` (held-out gap ``ours_gap``) beats ``theirs`` where only the margin's
        absolute floor keeps it from doing so: by ``min_gain`` on this draw, and on the redraws
        (:meth:`~lidar_weather_sim.gap.evaluation.GapEvaluator.beats_on_redraws`). False when a set is not known."""
        return ours is not None and theirs is not None and self.decisive(ours_gap, ours, theirs_gap, theirs)

    def refit_with_others(self, fitted: list[tuple]) -> list[tuple]:
        """The best of each effect's variants among ``fitted`` (beside, rival, fit gap, evaluations), by its fit gap,
        refitted together with the effects beside it (:meth:`refit`); the others as they are. A general rival
        that darkens every return trades off with a fog fitted beside the effect it replaces: behind OS1 draw case
        15's wet road (fog 47.9 m), dirt fitted alone reached 0.954 (held-out gap 0.0246 against the wet road's
        0.0144); refitted with the fog, fog 50.3 m and dirt 0.900 (0.0101; hidden: 51.4 m and 0.889)."""
        best: dict[str, int] = {}
        for i, (_, rival, gap, _) in enumerate(fitted):
            if rival.name not in best or gap < fitted[best[rival.name]][2]:
                best[rival.name] = i
        out = list(fitted)
        for i in best.values():
            beside, rival, _, n = fitted[i]
            *again, moved = self.refit(beside + [rival])
            out[i] = (again, moved, self.gap(again + [moved], "fit"), n)
        return out

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
