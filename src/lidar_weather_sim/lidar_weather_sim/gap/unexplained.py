"""After the search: what the effects leave unexplained, zone by zone, and which accepted effects may be named.

The search (:mod:`lidar_weather_sim.gap.search`) accepts whatever shrinks the held-out gap by its margin; when the
model has no effect for what the recording shows, the closest one wins (a Beer-Lambert fog fitted as sun). This
module is the judgement after it, on the held-out frames:

**Residual by zone** (:func:`zone_residuals`). Every zone of :mod:`~lidar_weather_sim.gap.signatures` is cut into
range bands (:data:`BANDS`: the cover zone and the near field one band each, the zones beyond 5 m at 5-15-30-60-150
m). In each band the measured returns ``M`` and the simulated ones ``S`` (sums over the ``n`` held-out frames of the
zone's linearly binned range histogram) differ by ``D = M - S``; chance alone gives ``sigma = sqrt(sum w^2 (M) + sum
w^2 (S))`` (Poisson, each return's weight in the band squared: the counting noise of both sides' ``n`` frames),
and, since the effects were fitted to the calibration frames' counts, the counting noise of the measured
calibration frames' per-frame mean as well (``sqrt(sum w^2 (M_cal)) / n_cal``). A
band's residual is significant when ``|D| >= SIGMA sigma`` (3) and ``|D| >= MIN_RELATIVE max(M, S)``
(:data:`MIN_RELATIVE`: a band of 10^5 returns is significant at 3 sigma from a 0.4 % change, below what a scene
model gets right; the floor is stated in the report). A zone's residual (returns per frame) is the sum over its
bands of what ``|D|`` exceeds both thresholds by; it is significant when that is above 0, and then reported with
its largest band's ``|D| / sigma`` and a shape from a fixed vocabulary (:data:`SHAPES`; ``no residual`` for a zone
without one), computed from the numbers:

- cover zone, near field: ``excess returns`` / ``missing returns`` (the sign of ``D``);
- the zones beyond 5 m: the sign of the zone's ``D`` (``loss`` / ``excess``) and the trend of ``ln(M / S)`` over
  its bands (weighted least squares, the weights from the counting noise): ``growing with range`` / ``falling
  with range`` when the slope is >= 3 of its standard errors and moves the ratio by ``MIN_RELATIVE`` or more over
  the bands, else ``uniform``. ``loss growing with range``: the measured frames lose ever more of the far returns
  (an extinction the model lacks).

Besides the counts, each zone's EPW and intensity distributions (echoes summed, each a histogram of
:mod:`~lidar_weather_sim.gap.signatures`) are compared in shape: the simulated histogram is scaled to the measured
total and each bin is a band of the rule above, and what the bins exceed their thresholds by must also come to
:data:`MIN_SHAPE` (10 %) of the zone's returns; a zone with a residual there is reported ``wider pulses`` /
``narrower pulses`` or ``returns brighter`` / ``returns dimmer`` (the sign of the change of the mean). A raised
noise floor (the sun) widens the pulses of every surface more than it changes their count.

**Naming rule** (:func:`judge_effects`). Each weather effect declares the zones that are its physics
(:data:`EFFECT_ZONES`), and the fog only its range counts (:data:`EFFECT_ASPECTS`: the range law of its loss; how the
pulses' widths and bytes answer it is the unit's receiver). An accepted effect is named only when, on the held-out frames, (1) one of its zones has a
significant residual without it (the other accepted effects in place): it had something to explain there; and
(2) with it, each of its zones' residual is no longer significant or is at most :data:`REMAINING` (20 %) of what it
was without it. An effect that shrinks the total gap while its own zones keep their residual (or gain one) is
refused: it stays in the search's fit (``effects`` of gap.json, the patched scenario) but is not named, and the
zones the named effects leave significant are reported as unexplained. A weather effect fitted at the weak end of its
search range (:func:`at_weak_end`: fog of 1000 m, dirt of 0.995, rain of 0.2 mm/h) is refused too: the search
could not tell it from no such effect, and what it took is something else's (draw case 4: a fog of 1000 m took the
extinction of a snow whose drops the model fitted at 0.16 mm/h for 4.4). So is one that does not beat every other
effect of the round it won by the margin a new effect must win (:func:`not_told_apart`; its held-out gap not below
:meth:`~lidar_weather_sim.gap.evaluation.GapEvaluator.gap_to_beat` of theirs): the search would not have taken it in
place of them, so the data did not tell them apart and a name would be a coin toss (draw case 21: the soft echoes of
`fog_spread`, fitted beside its fog as a snow of 0.64 mm/h that a rain of 2.2 mm/h matched; case 28: the loss of a
rain of 6.8 mm/h behind dirt, fitted as a fog of 189 m that a rain of 0.78 mm/h matched); the rivals are those of
the round it won judged again at the end, each fitted in its place beside the others as they ended
(:meth:`~lidar_weather_sim.gap.search.GapSearch.conflict_rivals`). A rain or a snow is named only where its drops'
echoes have the recording's shape (:func:`unlike_its_drops`): each of the near zone's range, EPW and intensity terms
of the gap with every accepted effect in place at most :data:`DROP_SHAPE_LIMIT`; a count of echoes matched by the rate
alone is not a rain (fixed-generator case 1: a rain of 9.9 mm/h fitted for `fog_spread`'s soft echoes, near-field
terms 0.13-0.26; the model's or the independent reference's own rain and snow: at most 0.007). The sensor family's
effects (read off the data, or the unit's response) have no zones here and are named as the search accepts them.

**On a twin of the recording** (a scene whose reflectivity was read off the recording's own returns, through the air
it had: :attr:`~lidar_weather_sim.scene.scene.Scene.recorded_range_m`, which the search gives back for every weather
it tries) the surfaces' loss is in the scene: any fog or rain returns the recorded surfaces as recorded, and what
tells the weather is what the twin could not mesh, its own echoes. The atmosphere's effects are then judged on the
near field (:data:`TWIN_EFFECT_ZONES`); a wet road darkens only what the twin already holds dark, and is not named.

Cost: one held-out re-simulation with all accepted effects, one without each accepted weather effect, and one with
the named effects only when one is refused.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from lidar_weather_sim.gap.signatures import RANGE_EDGES, ZONES, Signature, gap_terms
from lidar_weather_sim.scenario.effects import Effect

SIGMA = 3.0  # a band's residual counts beyond this many standard deviations of the counting noise
#: ... and beyond this share of its returns: at 10^5 returns 3 sigma is 0.4 %, less than any scene model gets right
MIN_RELATIVE = 0.05
#: a distribution's residual counts when it is at least this share of the zone's returns: the model's own fog at 80.2 m
#: and sun at 404 W/m^2 fitted to 80 m and 400 W/m^2 leave 6 % of the near field's 1740 returns/frame in its EPW bins
MIN_SHAPE = 0.10
WEAK_END = 0.01  # a main parameter within this share of its weakest bound is at the weak end of the range
REMAINING = 0.2  # with the effect, its zones' residual must be gone or at most this share of what it was without it
MIN_TREND_RETURNS = 20.0  # bands with fewer returns (both sides) do not enter the trend of the ratio
#: rain and snow are named only where their drops' echoes have the recording's near-field shape: each of the near
#: zone's range, EPW and intensity terms of the gap (systematic Bray-Curtis) with every accepted effect in place at
#: most this. The model's or the independent reference's rain and snow fitted to their own: 0.000-0.007; a rain fitted
#: for a generator's fog echoes (fixed-generator case 1): 0.13-0.26; a rain fitted at a quarter of `precip_dsd`'s
#: rate, whose drops lie nearer (fixed-generator case 3): its range 0.20
DROP_SHAPE_LIMIT = 0.05
DROP_EFFECTS = ("atmosphere.rain", "atmosphere.snow")
DROP_TERMS = ("near/range", "near/epw", "near/intensity")
RANGE_ZONES = ("body", "wake", "road", "far")
BANDS: dict[str, tuple[tuple[float, float], ...]] = {
    "cover": ((0.0, 0.5),),
    "near": ((0.5, 5.0),),
    **{z: ((5.0, 15.0), (15.0, 30.0), (30.0, 60.0), (60.0, 150.0)) for z in RANGE_ZONES},
}
ZONE_LABELS = {"cover": "cover zone", "near": "near field", "body": "vehicle bodies", "wake": "vehicle wakes",
               "road": "road", "far": "far field"}  # fmt: skip
SHAPES = ("excess returns", "missing returns", "loss growing with range", "loss falling with range", "uniform loss",
          "excess growing with range", "excess falling with range", "uniform excess", "wider pulses",
          "narrower pulses", "returns brighter", "returns dimmer", "no residual")  # fmt: skip
#: the distributions compared besides the range counts (module doc): a zone's histogram of each, echoes summed
ASPECTS = {"epw": ("wider pulses", "narrower pulses"), "intensity": ("returns brighter", "returns dimmer")}
#: the zones that are each weather effect's physics (module doc): fog dims every surface more with range (its soft
#: echoes are the unit's backscatter gain as much as the fog's, fitted by the search:
#: :data:`lidar_weather_sim.gap.search.FOG_GAINS`; a near field they leave is reported, not held against the
#: name); rain and snow put discrete returns in the near field and dim the far one; a wet
#: road takes the road's returns; dirt or water on the cover returns from the cover and dims every direction; the
#: sun's false detections and raised threshold act beyond the near field; spray flies in the vehicles' wakes
EFFECT_ZONES: dict[str, tuple[str, ...]] = {
    "atmosphere.fog": RANGE_ZONES,
    "atmosphere.rain": ("near", "far"),
    "atmosphere.snow": ("near", "far"),
    "atmosphere.road_wet": ("road",),
    "cover.dirt": ("cover", "road", "far"),
    "cover.water": ("cover", "road", "far"),
    "sensor.sun": ("road", "far"),
    "spray": ("wake", "body"),
}

#: the zones that are an effect's physics on a twin of the recording (module doc), where not :data:`EFFECT_ZONES`:
#: the real OS1-128 street with the reference's fog of 50 m visual range, through its twin: the fog fitted at 49.85 m
#: and the held-out near field re-simulated at 124 814 returns for 125 220 recorded, while the far field, road and
#: bodies came back as recorded with any fog
TWIN_EFFECT_ZONES: dict[str, tuple[str, ...]] = {
    "atmosphere.fog": ("near",),
    "atmosphere.rain": ("near",),
    "atmosphere.snow": ("near",),
    "atmosphere.road_wet": (),
}

#: the aspects (range counts, :data:`ASPECTS`) an effect's naming judges in its zones, where not all: the fog's
#: physics is the range law of its loss; how a pulse's width and byte answer a weaker echo is the unit's receiver
#: (draw case 0, a Beer-Lambert fog whose pulses narrow as sqrt(ln(A/T)): fitted at 232 m for 229, held-out gap
#: 0.106 -> 0.006, the bodies' pulse widths kept 25 % of their residual, over :data:`REMAINING`)
EFFECT_ASPECTS: dict[str, tuple[str, ...]] = {"atmosphere.fog": ("range",)}


@dataclass(frozen=True)
class Band:
    """One range band of a zone: returns per frame measured and simulated, the counting noise of their difference
    (per frame) and the difference in those sigmas."""

    lo_m: float
    hi_m: float
    measured: float
    simulated: float
    noise: float
    sigma: float
    significant: bool
    noise_measured: float = 0.0  # each side's own counting noise (per frame)
    noise_simulated: float = 0.0


@dataclass(frozen=True)
class ZoneResidual:
    """A zone's residual (module doc): ``residual`` returns per frame beyond the thresholds, ``sigma`` the largest
    band's |D| / sigma, ``relative`` the zone's (M - S) / S (for a distribution: of the means), ``shape`` one of
    :data:`SHAPES`."""

    zone: str
    residual: float
    sigma: float
    relative: float
    shape: str
    bands: tuple[Band, ...]
    aspect: str = "range"  # or a distribution of :data:`ASPECTS` (its bands are then that quantity's bins)

    @property
    def significant(self) -> bool:
        return self.residual > 0.0

    @property
    def label(self) -> str:
        return ZONE_LABELS[self.zone]

    def text(self) -> str:
        """``far field, loss growing with range`` (the CLI's ``unexplained:`` lines)."""
        return f"{self.label}, {self.shape}"

    def to_dict(self) -> dict:
        out = asdict(self)
        out.update(label=self.label, bands=[asdict(b) for b in self.bands])
        if not np.isfinite(self.relative):  # returns where the model has none: no ratio (JSON has no infinity)
            out["relative"] = None
        return out


def _band_sums(sig: Signature, zone: str, lo: float, hi: float) -> tuple[float, float]:
    """(sum of weights, sum of squared weights) of the zone's range-histogram bins whose centres lie in [lo, hi)."""
    key = f"{zone}/range"
    if key not in sig.sums:
        return 0.0, 0.0
    edges = RANGE_EDGES[zone]
    centres = 0.5 * (edges[:-1] + edges[1:])
    inside = (centres >= lo) & (centres < hi)
    squares = sig.squares.get(key, sig.sums[key])
    return float(sig.sums[key][inside].sum()), float(squares[inside].sum())


def band_residual(m: float, m_sq: float, s: float, s_sq: float, frames_m: int, frames_s: int,
                  lo: float = 0.0, hi: float = 0.0, fit_noise: float = 0.0) -> tuple[Band, float]:  # fmt: skip
    """The :class:`Band` of sums ``m`` / ``s`` (squared weights ``m_sq`` / ``s_sq``) over ``frames_m`` / ``frames_s``
    frames, and its residual per frame beyond the thresholds (0 when not significant); ``fit_noise``: the counting
    noise (per frame) of the calibration frames the simulation's effects were fitted to, counted on its side."""
    nm, ns = max(frames_m, 1), max(frames_s, 1)
    a, b = m / nm, s / ns
    noise_m, noise_s = float(np.sqrt(m_sq)) / nm, float(np.hypot(np.sqrt(s_sq) / ns, fit_noise))
    noise = float(np.hypot(noise_m, noise_s))
    d = a - b
    threshold = max(SIGMA * noise, MIN_RELATIVE * max(a, b))
    excess = float(max(abs(d) - threshold, 0.0)) if abs(d) > 0 else 0.0  # plain floats: gap.json takes them
    sigma = abs(d) / noise if noise > 0 else (np.inf if d else 0.0)
    return Band(float(lo), float(hi), float(a), float(b), noise, float(sigma), excess > 0, noise_m, noise_s), excess


def range_trend(bands: list[Band]) -> tuple[float, float, float]:
    """(slope per m, its standard error, the span of the bands' centres in m) of ln(M / S) over the bands' centre
    ranges: weighted least squares, each band weighted by the inverse of var(ln M) + var(ln S) from its counting
    noise; bands with fewer than :data:`MIN_TREND_RETURNS` returns per frame on both sides together are left out,
    and an empty side is taken at a tenth of a return per frame."""
    rows = [b for b in bands if b.measured + b.simulated >= MIN_TREND_RETURNS]
    if len(rows) < 2:
        return 0.0, np.inf, 0.0
    x = np.array([0.5 * (b.lo_m + b.hi_m) for b in rows])
    m = np.maximum([b.measured for b in rows], 0.1)
    s = np.maximum([b.simulated for b in rows], 0.1)
    y = np.log(m / s)
    var = (np.array([b.noise_measured for b in rows]) / m) ** 2 + (np.array([b.noise_simulated for b in rows]) / s) ** 2
    w = 1.0 / np.maximum(var, 1e-12)
    xm = np.sum(w * x) / np.sum(w)
    sxx = np.sum(w * (x - xm) ** 2)
    if sxx <= 0:
        return 0.0, np.inf, 0.0
    slope = float(np.sum(w * (x - xm) * (y - np.sum(w * y) / np.sum(w))) / sxx)
    return slope, float(np.sqrt(1.0 / sxx)), float(x.max() - x.min())


def shape_of(zone: str, bands: list[Band]) -> str:
    """The zone's shape (:data:`SHAPES`, module doc) from its bands."""
    d = sum(b.measured - b.simulated for b in bands)
    if zone not in RANGE_ZONES:
        return "excess returns" if d > 0 else "missing returns"
    sign = "excess" if d > 0 else "loss"
    slope, se, span = range_trend(bands)
    if not (abs(slope) >= SIGMA * se and abs(slope) * span >= np.log1p(MIN_RELATIVE)):
        return f"uniform {sign}"
    ratio_up = slope > 0  # measured / simulated rises with range
    growing = ratio_up if sign == "excess" else not ratio_up
    return f"{sign} {'growing' if growing else 'falling'} with range"


def zone_residual(zone: str, measured: Signature, simulated: Signature,
                  calibration: Signature | None = None) -> ZoneResidual:  # fmt: skip
    """One zone's :class:`ZoneResidual` between the measured and simulated signatures (the same frames);
    ``calibration``: the measured calibration frames the effects were fitted to (their counting noise counts too)."""
    bands, residual = [], 0.0
    for lo, hi in BANDS[zone]:
        m, m_sq = _band_sums(measured, zone, lo, hi)
        s, s_sq = _band_sums(simulated, zone, lo, hi)
        fit_noise = 0.0
        if calibration is not None and calibration.frames:
            fit_noise = float(np.sqrt(_band_sums(calibration, zone, lo, hi)[1])) / calibration.frames
        band, excess = band_residual(m, m_sq, s, s_sq, measured.frames, simulated.frames, lo, hi, fit_noise)
        bands.append(band)
        residual += excess
    total_m, total_s = sum(b.measured for b in bands), sum(b.simulated for b in bands)
    relative = (total_m - total_s) / total_s if total_s > 0 else (np.inf if total_m > 0 else 0.0)
    sigma = max((b.sigma for b in bands if b.significant), default=max((b.sigma for b in bands), default=0.0))
    shape = shape_of(zone, bands) if residual > 0 else "no residual"
    return ZoneResidual(zone, float(residual), float(sigma), float(relative), shape, tuple(bands))


def distribution_residual(zone: str, aspect: str, measured: Signature, simulated: Signature) -> ZoneResidual | None:
    """The zone's residual in the shape of its ``aspect`` distribution (EPW or intensity, echoes summed; module
    doc): the simulated histogram scaled to the measured total, each bin a band of :func:`band_residual`; the shape
    from the sign of the change of the mean. None when either side has less than one return per frame (the range
    counts judge that zone) or the signatures lack the histogram."""
    key = f"{zone}/{aspect}"
    if key not in measured.sums or key not in simulated.sums:
        return None
    nm, ns = max(measured.frames, 1), max(simulated.frames, 1)

    def folded(sig: Signature, store: dict) -> np.ndarray:
        values = store.get(key, sig.sums[key])
        return values.reshape(3, -1).sum(axis=0)

    m, m_sq = folded(measured, measured.sums), folded(measured, measured.squares)
    s, s_sq = folded(simulated, simulated.sums), folded(simulated, simulated.squares)
    if m.sum() / nm < 1.0 or s.sum() / ns < 1.0:
        return None
    k = (m.sum() / nm) / (s.sum() / ns)  # the simulated returns scaled to the measured count: shape only
    centres = np.arange(len(m)) + 0.5
    bands, residual = [], 0.0
    for i in range(len(m)):
        band, excess = band_residual(m[i], m_sq[i], k * s[i], k * k * s_sq[i], nm, ns, float(i), float(i + 1))
        bands.append(band)
        residual += excess
    if residual < MIN_SHAPE * m.sum() / nm:  # a shape this close is what a fit's own error leaves
        residual = 0.0
    sigma = max((b.sigma for b in bands if b.significant), default=max((b.sigma for b in bands), default=0.0))
    more, less = ASPECTS[aspect]
    mean_m, mean_s = float(np.sum(centres * m) / m.sum()), float(np.sum(centres * s) / s.sum())
    shape = (more if mean_m > mean_s else less) if residual > 0 else "no residual"
    return ZoneResidual(zone, float(residual), float(sigma), mean_m / mean_s - 1.0, shape, tuple(bands), aspect)


def zone_residuals(measured: Signature, simulated: Signature,
                   calibration: Signature | None = None) -> dict[str, ZoneResidual]:  # fmt: skip
    """Every zone's :class:`ZoneResidual` (module doc; ``calibration``: :func:`zone_residual`): by zone name for
    the range counts, ``zone/epw`` and ``zone/intensity`` for the distributions (:func:`distribution_residual`)."""
    out = {zone: zone_residual(zone, measured, simulated, calibration) for zone in ZONES}
    for zone in ZONES:
        for aspect in ASPECTS:
            residual = distribution_residual(zone, aspect, measured, simulated)
            if residual is not None:
                out[f"{zone}/{aspect}"] = residual
    return out


def _of_zones(residuals: dict[str, ZoneResidual], zones: tuple[str, ...],
              aspects: tuple[str, ...] | None = None) -> list[str]:  # fmt: skip
    """The keys of ``residuals`` in ``zones`` (of ``aspects``; None: every aspect)."""
    return [k for k, r in residuals.items() if r.zone in zones and (aspects is None or r.aspect in aspects)]


def effect_zones(name: str, twin: bool = False) -> tuple[str, ...] | None:
    """The zones that are the effect ``name``'s physics (None: it has none, the sensor family), on a twin of the
    recording when ``twin`` (module doc)."""
    return TWIN_EFFECT_ZONES.get(name, EFFECT_ZONES.get(name)) if twin else EFFECT_ZONES.get(name)


def removes_its_residual(name: str, without: dict[str, ZoneResidual], with_it: dict[str, ZoneResidual],
                         twin: bool = False) -> str | None:  # fmt: skip
    """Why the effect ``name`` may not be named (None: it may), from the zones' residuals without it and with it
    (the other accepted effects in place both times): module doc, the naming rule (``twin``: on a twin of the
    recording). Effects without zones (the sensor family) always may."""
    zones, aspects = effect_zones(name, twin), EFFECT_ASPECTS.get(name)
    if zones is None:
        return None
    if not zones:
        return "a twin of the recording holds what it changes in its reflectivity: not told apart from the scene"
    if not any(without[k].significant for k in _of_zones(without, zones, aspects)):
        return f"no residual to remove in its zones ({', '.join(ZONE_LABELS[z] for z in zones)})"
    empty = ZoneResidual("", 0.0, 0.0, 0.0, "no residual", ())
    left = [k for k in _of_zones(with_it, zones, aspects)
            if with_it[k].significant and with_it[k].residual > REMAINING * without.get(k, empty).residual]  # fmt: skip
    if left:
        return "leaves " + "; ".join(
            f"{with_it[k].text()} ({with_it[k].sigma:.1f} sigma, {with_it[k].residual:.1f} returns/frame, "
            f"{without.get(k, empty).residual:.1f} without it)" for k in left)  # fmt: skip
    return None


def at_weak_end(effect: Effect) -> str | None:
    """Why the weather effect ``effect`` may not be named because it sits at the weak end of its search range (within
    :data:`WEAK_END` of the bound where it is closest to absent: the largest visual range or transmission, the
    smallest rate, film or irradiance), else None (module doc)."""
    spec = effect.spec
    if spec.family != "weather" or spec.categorical:
        return None
    weak = spec.bounds[1] if spec.main in ("visual_range", "transmission") else spec.bounds[0]
    if abs(effect.value / weak - 1.0) > WEAK_END:
        return None
    return (f"at the weak end of its range ({spec.main} {effect.value:.4g} {spec.unit}): "
            "not told apart from none, it stands for something else")


@dataclass
class Judgement:
    """The judgement after the search: which accepted effects are named, which are refused (with why), and the
    zones the named effects leave unexplained."""

    named: list[Effect] = field(default_factory=list)
    refused: list[tuple[Effect, str]] = field(default_factory=list)
    unexplained: list[ZoneResidual] = field(default_factory=list)
    residuals: dict[str, ZoneResidual] = field(default_factory=dict)  # every zone, with the named effects

    twin: bool = False  # judged as on a twin of the recording (module doc)

    def rule(self) -> dict:
        return {"sigma": SIGMA, "min_relative": MIN_RELATIVE, "remaining": REMAINING, "twin": self.twin,
                "effect_zones": {k: list(effect_zones(k, self.twin)) for k in EFFECT_ZONES},
                "effect_aspects": {k: list(v) for k, v in EFFECT_ASPECTS.items()}}  # fmt: skip


def unlike_its_drops(terms: dict[str, float]) -> str | None:
    """Why a rain or a snow may not be named because the near field's echoes with it in place do not have the
    recording's shape (``terms``: the gap's terms with every accepted effect; :data:`DROP_SHAPE_LIMIT`), else None:
    a count of drops matched by the rate alone is not a rain or a snow."""
    off = [f"{k} {terms[k]:.3f}" for k in DROP_TERMS if terms.get(k, 0.0) > DROP_SHAPE_LIMIT]
    if not off:
        return None
    return f"its drops' echoes are not the near field's ({', '.join(off)}; at most {DROP_SHAPE_LIMIT:g})"


def not_told_apart(effect: Effect, rivals) -> str | None:
    """Why the weather effect ``effect`` may not be named because it did not beat other effects by the search's
    margin (``rivals``: their candidates, with ``effect`` and ``heldout_gap``; module doc), else None."""
    if not rivals:
        return None
    listed = ", ".join(f"{c.effect.label()} (held-out gap {c.heldout_gap:.4f})" for c in rivals)
    return f"not told apart from {listed}: not beaten by the margin a new effect must win"


def judge_effects(accepted: list[Effect], measured: Signature, simulate, calibration: Signature | None = None,
                  twin: bool = False, rivals: list | None = None) -> Judgement:  # fmt: skip
    """:class:`Judgement` of the search's ``accepted`` effects against the ``measured`` held-out signature;
    ``simulate(effects)`` gives the held-out frames' simulated :class:`Signature` with ``effects``; ``calibration``:
    the measured frames the effects were fitted to (:func:`zone_residual`); ``twin``: the scene is a twin of the
    recording (module doc); ``rivals``: per accepted effect, the other effects' candidates it did not beat by the
    search's margin (:func:`lidar_weather_sim.gap.search.rivals`; None: none)."""

    def residuals(effects: list[Effect]) -> dict[str, ZoneResidual]:
        return zone_residuals(measured, simulate(effects), calibration)

    simulated = simulate(accepted)
    with_all = zone_residuals(measured, simulated, calibration)
    shape = gap_terms(measured, simulated) if any(e.name in DROP_EFFECTS for e in accepted) else {}
    out = Judgement(twin=twin)
    for i, effect in enumerate(accepted):
        reason = at_weak_end(effect)
        if reason is None and effect.name in DROP_EFFECTS:
            reason = unlike_its_drops(shape)
        if reason is None and effect.name in EFFECT_ZONES:
            without = residuals(accepted[:i] + accepted[i + 1 :])
            reason = removes_its_residual(effect.name, without, with_all, twin)
        if reason is None and effect.name in EFFECT_ZONES and rivals is not None:
            reason = not_told_apart(effect, rivals[i])
        if reason is None:
            out.named.append(effect)
        else:
            out.refused.append((effect, reason))
    out.residuals = residuals(out.named) if out.refused else with_all
    out.unexplained = sorted((r for r in out.residuals.values() if r.significant), key=lambda r: -r.sigma)
    return out
