"""Named weather and sensor effects as scenario patches: what ``make-measured`` hides and ``gap`` finds.

An effect is a name and parameters; its first parameter is the main one, in these units:

=========================  ==============  ==================================================
name                       main parameter  model
=========================  ==============  ==================================================
atmosphere.fog             visual_range    m; region ``atmosphere``, fog class (Koschmieder);
                                           ``gain`` (0-1, default 1): its ``fog_backscatter_gain``
atmosphere.rain            intensity       mm/h; region ``atmosphere``, rain class
atmosphere.snow            intensity       mm/h water equivalent; ``atmosphere``, snow class
atmosphere.road_wet        water_film      mm on the road; ``atmosphere`` with ``air: false``
cover.dirt                 transmission    mean one-way (0-1); region ``cover``, ``dirt:<T>``
                                           (or ``sample=3l``: that thesis sample at mean T);
                                           ``gain`` (0-1, default 1): its ``texture_return_gain``;
                                           ``forward`` (0-1, default the texture's): its ``forward_share``;
                                           ``contrast`` (0-1, default 1): its ``texture_contrast``
cover.water                transmission    mean one-way (0-1); ``cover``, ``water_film``
sensor.sun                 irradiance      W/m^2; the receiver's noise floor
spray                      water_film      mm; region ``spray`` (``actor=ID`` picks the emitter)
sensor.intensity_gamma     gamma           1; ``sensor.response`` (the unit's intensity response)
sensor.intensity_scale     scale           1; ``sensor.response``
sensor.range_bias          bias            m, signed; ``sensor.response``
sensor.range_noise         sigma           m, on top of the profile's; ``sensor.response``
sensor.ray_drop            probability     1, of a return at intensity 0; ``sensor.response``
sensor.return_mode         mode            one of strongest, last, dual, first, all (chosen, not
                                           fitted); ``sensor.return_mode``
sensor.dead_channels       channels        channels joined by ``+`` (e.g. ``3+17``), read off the
                                           recording (:mod:`lidar_weather_sim.gap.channels`);
                                           region ``faults``, ``dead_channels``
sensor.weak_channels       gains           ``channel:gain`` joined by ``+`` (e.g. ``3:0.5+17:0.25``; gain
                                           0-1 of the channel's receiver), read off the recording;
                                           region ``faults``, ``channel_gains``
sensor.elevation_offsets   offsets         ``channel:deg`` joined by ``+`` (e.g. ``3:0.2+17:-0.15``),
                                           read off the recording; ``sensor.elevation_offsets_deg``
sensor.beam_origin         z               m, signed: the beams' origin above the points' frame origin;
                                           ``sensor.beam_origin_z_m``
sensor.beam_origin_radial  radius          m: the beams' origin off the spin axis, in the points' frame;
                                           ``sensor.beam_origin_radial_m``
sensor.near_field_ghost    rate            ghosts per beam and frame: returns of the clean window and
                                           housing at 0-0.5 m; region ``cover``,
                                           ``near_field_ghost_per_beam``
=========================  ==============  ==================================================

The ``sensor.intensity_*``, ``range_*`` and ``ray_drop`` effects are the unit's own departures from
the model (:mod:`lidar_weather_sim.sensor.response`), family ``sensor``, with the return mode the
driver was set to; the others are the ``weather`` family (the sun included: it is light from outside).
The return mode is *categorical*: its main parameter is one of the spec's ``choices``, which the
search tries one by one (:func:`search_grid` gives their indices) instead of fitting a number. The dead
and weak channels and the elevation offsets are *read off the data*: the search proposes the one set the
recording shows and tries it.

Each effect changes only itself: rain does not wet the road (``road_water_film_mm: 0``
unless ``atmosphere.road_wet`` is applied too) and does not feed spray, and snow falls without
covering the road (no snow cover unless the scenario's ``weather.road.snow_depth_m`` sets one: a scene
state, not the snowfall), so the effects hidden in a recording are exactly the ones named.
:func:`apply_effects` returns a new, validated :class:`~lidar_weather_sim.scenario.schema.Scenario`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lidar_weather_sim.core.names import RETURN_MODES
from lidar_weather_sim.scenario.schema import Scenario


@dataclass(frozen=True)
class EffectSpec:
    """An effect the model knows: its main parameter, unit, search bounds and extra keys."""

    name: str
    main: str
    unit: str
    bounds: tuple[float, float]
    log_search: bool  # search the main parameter on a log scale
    extras: tuple[str, ...] = ()
    family: str = "weather"  # or "sensor": the unit's own departures from the model
    signed: bool = False  # the main parameter may be 0 or negative (else it must be above 0)
    choices: tuple[str, ...] = ()  # a categorical effect: its main parameter is one of these
    from_data: bool = False  # the main parameter is a text read off the recording, tried as it is
    evident: bool = False  # the data alone proves it (a channel silent where the model returns): see gap.evaluation.GapEvaluator.earns_margin

    @property
    def categorical(self) -> bool:
        """The main parameter is a text (a choice or read off the data), not a number."""
        return bool(self.choices) or self.from_data


EFFECTS: dict[str, EffectSpec] = {
    s.name: s
    for s in (
        EffectSpec("atmosphere.fog", "visual_range", "m", (15.0, 1000.0), True, ("gain",)),
        EffectSpec("atmosphere.rain", "intensity", "mm/h", (0.2, 100.0), True),
        EffectSpec("atmosphere.snow", "intensity", "mm/h", (0.05, 10.0), True),
        EffectSpec("atmosphere.road_wet", "water_film", "mm", (0.03, 5.0), True),
        EffectSpec("cover.dirt", "transmission", "1", (0.2, 0.995), False, ("sample", "gain", "forward", "contrast")),
        EffectSpec("cover.water", "transmission", "1", (0.2, 0.995), False),
        EffectSpec("sensor.sun", "irradiance", "W/m^2", (10.0, 1200.0), True),
        EffectSpec("spray", "water_film", "mm", (0.05, 3.0), True, ("actor",)),
        EffectSpec("sensor.intensity_gamma", "gamma", "1", (0.25, 4.0), True, family="sensor"),
        EffectSpec("sensor.intensity_scale", "scale", "1", (0.25, 4.0), True, family="sensor"),
        EffectSpec("sensor.range_bias", "bias", "m", (-0.3, 0.3), False, family="sensor", signed=True),
        EffectSpec("sensor.range_noise", "sigma", "m", (0.003, 0.3), True, family="sensor"),
        EffectSpec("sensor.ray_drop", "probability", "1", (0.01, 0.95), True, family="sensor"),
        EffectSpec("sensor.return_mode", "mode", "", (0.0, len(RETURN_MODES) - 1.0), False, family="sensor",
                   choices=RETURN_MODES),
        EffectSpec("sensor.dead_channels", "channels", "", (0.0, 0.0), False, family="sensor", from_data=True,
                   evident=True),
        EffectSpec("sensor.weak_channels", "gains", "", (0.0, 0.0), False, family="sensor", from_data=True),
        EffectSpec("sensor.elevation_offsets", "offsets", "deg", (0.0, 0.0), False, family="sensor",
                   from_data=True),
        EffectSpec("sensor.beam_origin", "z", "m", (-0.15, 0.15), False, family="sensor", signed=True),
        EffectSpec("sensor.beam_origin_radial", "radius", "m", (0.002, 0.1), True, family="sensor"),
        EffectSpec("sensor.near_field_ghost", "rate", "1/beam", (0.003, 3.0), True, family="sensor"),
    )
}
FAMILIES = ("weather", "sensor")
#: sensor effect -> the field of ``sensor.response`` it sets
RESPONSE_FIELDS = {"sensor.intensity_gamma": "intensity_gamma", "sensor.intensity_scale": "intensity_scale",
                   "sensor.range_bias": "range_bias_m", "sensor.range_noise": "range_noise_m",
                   "sensor.ray_drop": "drop_probability"}  # fmt: skip
PRECIPITATION = ("atmosphere.rain", "atmosphere.snow")


@dataclass(frozen=True)
class Effect:
    """One effect with its parameters (``params[spec.main]`` is the main one)."""

    name: str
    params: dict[str, float | str] = field(default_factory=dict)

    @property
    def spec(self) -> EffectSpec:
        return EFFECTS[self.name]

    @property
    def value(self) -> float:
        """The main parameter; for a categorical effect the index of its choice (0 when read off the data)."""
        spec = self.spec
        if spec.from_data:
            return 0.0
        if spec.categorical:
            return float(spec.choices.index(str(self.params[spec.main])))
        return float(self.params[spec.main])

    def with_value(self, value: float) -> "Effect":
        """This effect with main parameter ``value`` (categorical: the choice at index ``round(value)``; read
        off the data: this effect as it is)."""
        spec = self.spec
        if spec.from_data:
            return self
        main = spec.choices[int(round(value))] if spec.categorical else float(value)
        return Effect(self.name, {**self.params, spec.main: main})

    def label(self) -> str:
        extra = "".join(f",{k}={v}" for k, v in self.params.items() if k != self.spec.main)
        main = self.params[self.spec.main] if self.spec.categorical else f"{self.value:g}"
        return f"{self.name}:{self.spec.main}={main}{extra}"


def parse_effect(text: str) -> Effect:
    """``NAME:key=value[,key=value...]`` (e.g. ``atmosphere.fog:visual_range=60``) -> Effect.

    A value without a key is the main parameter; ``cover.dirt:sample=3l`` alone takes the
    sample's own mean transmission. Raises ValueError naming the problem."""
    name, _, rest = text.partition(":")
    if name not in EFFECTS:
        raise ValueError(f"--hide {text!r}: unknown effect '{name}' (known: {', '.join(EFFECTS)})")
    spec = EFFECTS[name]
    params: dict[str, float | str] = {}
    for item in filter(None, rest.split(",")):
        key, eq, value = item.partition("=")
        key, value = (key, value) if eq else (spec.main, key)
        if key not in (spec.main, *spec.extras):
            raise ValueError(f"--hide {text!r}: effect '{name}' has no parameter '{key}' "
                             f"(parameters: {', '.join((spec.main, *spec.extras))})")  # fmt: skip
        if key in params:
            raise ValueError(f"--hide {text!r}: parameter '{key}' given twice")
        if key == "sample":
            params[key] = value
            continue
        if key == spec.main and spec.from_data:
            params[key] = (format_channel_values(parse_channel_values(name, value, text)) if name in CHANNEL_VALUES
                           else "+".join(str(c) for c in parse_channels(value, text)))  # fmt: skip
            continue
        if key == spec.main and spec.categorical:
            if value not in spec.choices:
                raise ValueError(f"--hide {text!r}: '{key}' must be one of {', '.join(spec.choices)}, got '{value}'")
            params[key] = value
            continue
        try:
            params[key] = int(value) if key == "actor" else float(value)
        except ValueError:
            raise ValueError(f"--hide {text!r}: parameter '{key}' needs a number, got '{value}'") from None
        if key == spec.main and spec.signed and not abs(params[key]) < float("inf"):
            raise ValueError(f"--hide {text!r}: '{key}' must be a finite number ({spec.unit}), got {value}")
        if key == spec.main and not spec.signed and not 0.0 < params[key] < float("inf"):
            raise ValueError(f"--hide {text!r}: '{key}' must be a finite number above 0 ({spec.unit}), got {value}")
        if key == "gain" and not 0.0 <= params[key] <= 1.0:
            raise ValueError(f"--hide {text!r}: 'gain' is a share of the light the unit reports, within [0, 1], got {value}")
        if key == "contrast" and not 0.0 <= params[key] <= 1.0:
            raise ValueError(f"--hide {text!r}: 'contrast' scales the dirt's patches around its mean (0: a uniform "
                             f"film), within [0, 1], got {value}")  # fmt: skip
        if key == "forward" and not 0.0 <= params[key] <= 1.0:
            raise ValueError(f"--hide {text!r}: 'forward' is a share of the beam energy the dirt scatters forward, "
                             f"within [0, 1], got {value}")  # fmt: skip
        if key == spec.main and spec.main in ("transmission", "probability") and params[key] > 1.0:
            raise ValueError(f"--hide {text!r}: '{key}' is a {spec.main}, at most 1, got {value}")
    if spec.main not in params:
        if name == "cover.dirt" and "sample" in params:
            from lidar_weather_sim.regions.cover_textures import load_samples

            sample = str(params["sample"])
            samples = load_samples().samples
            if sample not in samples or sample == "water_film":
                raise ValueError(f"--hide {text!r}: unknown dirt sample '{sample}' (known: "
                                 f"{', '.join(k for k in samples if k != 'water_film')})")  # fmt: skip
            params[spec.main] = samples[sample].mean_transmission
        else:
            raise ValueError(f"--hide {text!r}: effect '{name}' needs its main parameter '{spec.main}' ({spec.unit})")
    return Effect(name, params)


#: effects read off the data whose main parameter is ``channel:value`` pairs -> (what the value is, its bounds)
CHANNEL_VALUES = {"sensor.weak_channels": ("a gain", (0.0, 1.0)),
                  "sensor.elevation_offsets": ("an offset in deg", (-10.0, 10.0))}  # fmt: skip


def parse_channel_values(name: str, value: str, text: str = "") -> dict[int, float]:
    """``3:0.5+17:0.25`` -> {3: 0.5, 17: 0.25} for effect ``name`` (:data:`CHANNEL_VALUES`); ValueError naming
    ``text`` when a pair is not a channel from 0 and a value within the effect's bounds."""
    what, (lo, hi) = CHANNEL_VALUES[name]
    out: dict[int, float] = {}
    for pair in value.split("+"):
        channel, colon, number = pair.partition(":")
        try:
            c, v = int(channel), float(number)
        except ValueError:
            c, v = -1, float("nan")
        if not colon or c < 0 or c in out or not lo <= v <= hi:
            raise ValueError(f"--hide {text or value!r}: '{pair}' must be CHANNEL:VALUE, a channel from 0 (once) "
                             f"and {what} within [{lo:g}, {hi:g}] (e.g. 3:0.5+17:0.25)")  # fmt: skip
        out[c] = v
    return dict(sorted(out.items()))


def format_channel_values(values: dict[int, float]) -> str:
    """{3: 0.5, 17: 0.25} -> ``3:0.5+17:0.25`` (channels in order)."""
    return "+".join(f"{c}:{v:g}" for c, v in sorted(values.items()))


def parse_channels(value: str, text: str = "") -> list[int]:
    """``3+17`` -> [3, 17] (sorted, unique); ValueError naming ``text`` when it is not channels."""
    try:
        channels = sorted({int(c) for c in value.split("+")})
    except ValueError:
        channels = [-1]
    if not channels or channels[0] < 0:
        raise ValueError(f"--hide {text or value!r}: channels must be channel numbers from 0 joined by '+' "
                         f"(e.g. 3+17), got '{value}'")  # fmt: skip
    return channels


def conflicts(effects: list[Effect]) -> str | None:
    """Why ``effects`` cannot be applied together (None if they can)."""
    names = [e.name for e in effects]
    for name in set(names):
        if name != "spray" and names.count(name) > 1:
            return f"effect '{name}' given twice"
    spray = [e for e in effects if e.name == "spray"]
    if len({e.params.get("actor") for e in spray}) != len(spray):
        return "spray given twice for the same actor"
    if len({e.value for e in spray}) > 1:
        return "spray from several actors needs one water film (the road's) for all of them"
    if all(p in names for p in PRECIPITATION):
        return "precipitation is rain or snow, not both"
    if "cover.dirt" in names and "cover.water" in names:
        return "the cover holds one texture: cover.dirt or cover.water, not both"
    return None


def apply_effects(scenario: Scenario, effects: list[Effect]) -> Scenario:
    """``scenario`` with ``effects`` added (a new, validated Scenario; raises ValueError on conflicts)."""
    problem = conflicts(effects)
    if problem:
        raise ValueError(f"cannot apply {', '.join(e.label() for e in effects)}: {problem}")
    data = scenario.model_dump(mode="json")
    regions: list[str] = data["regions"]
    params: dict[str, dict] = data["region_params"]

    def region(name: str) -> dict:
        if name not in regions:
            regions.append(name)
        return params.setdefault(name, {})

    names = {e.name for e in effects}
    air = names & {"atmosphere.fog", *PRECIPITATION}
    if air or "atmosphere.road_wet" in names:
        atmo = region("atmosphere")
        atmo["air"] = bool(air)
        atmo.setdefault("road_water_film_mm", 0.0)
    spray_actors = []
    for e in effects:
        if e.name == "sensor.dead_channels":
            region("faults")["dead_channels"] = parse_channels(str(e.params["channels"]))
            continue
        if e.name == "sensor.weak_channels":
            region("faults")["channel_gains"] = parse_channel_values(e.name, str(e.params["gains"]))
            continue
        if e.name == "sensor.elevation_offsets":
            data["sensor"]["elevation_offsets_deg"] = parse_channel_values(e.name, str(e.params["offsets"]))
            continue
        if e.spec.categorical:  # the return mode
            data["sensor"]["return_mode"] = e.params[e.spec.main]
            continue
        v = e.value
        if e.name == "atmosphere.fog":
            region("atmosphere")["visual_range_m"] = v
            if "gain" in e.params:
                region("atmosphere")["fog_backscatter_gain"] = float(e.params["gain"])
        elif e.name in PRECIPITATION:
            atmo = region("atmosphere")
            atmo["precipitation_type"] = e.name.split(".")[1]
            atmo["intensity_mm_h"] = v
        elif e.name == "atmosphere.road_wet":
            region("atmosphere")["road_water_film_mm"] = v
        elif e.name == "cover.dirt":
            sample = e.params.get("sample")
            if sample:
                region("cover").update(texture=str(sample), mean_transmission=v)
            else:
                region("cover").update(texture=f"dirt:{v:.6g}", mean_transmission=None)
            if "gain" in e.params:
                region("cover")["texture_return_gain"] = float(e.params["gain"])
            if "forward" in e.params:
                region("cover")["forward_share"] = float(e.params["forward"])
            if "contrast" in e.params:
                region("cover")["texture_contrast"] = float(e.params["contrast"])
        elif e.name == "cover.water":
            region("cover").update(texture="water_film", mean_transmission=v)
        elif e.name == "sensor.beam_origin":
            data["sensor"]["beam_origin_z_m"] = v
        elif e.name == "sensor.beam_origin_radial":
            data["sensor"]["beam_origin_radial_m"] = v
        elif e.name == "sensor.near_field_ghost":
            region("cover")["near_field_ghost_per_beam"] = v
        elif e.name == "sensor.sun":
            data["weather"]["sun"]["irradiance_w_m2"] = v
        elif e.name in RESPONSE_FIELDS:
            data["sensor"]["response"][RESPONSE_FIELDS[e.name]] = v
        elif e.name == "spray":
            actor = e.params.get("actor", _default_emitter(scenario))
            spray_actors.append((int(actor), v))
    if spray_actors:
        region("spray").update(actor_ids=[a for a, _ in spray_actors], water_film_mm=spray_actors[0][1])
    return Scenario.model_validate(data)


def _default_emitter(scenario: Scenario) -> int:
    """The first actor flagged ``emits_spray``, else the first vehicle."""
    for actor in scenario.actors:
        if actor.emits_spray:
            return actor.id
    for actor in scenario.actors:
        if actor.type == "vehicle":
            return actor.id
    raise ValueError(f"scenario '{scenario.name}' has no vehicle to emit spray")


def spray_candidates(scenario: Scenario) -> list[int]:
    """Actor ids that may throw spray: the vehicles of the scenario."""
    return [a.id for a in scenario.actors if a.type == "vehicle"]


SIGNED_SPAN = 30.0  # a signed effect's grid: magnitudes from its largest / SIGNED_SPAN up, both signs


def search_grid(spec: EffectSpec, n: int) -> np.ndarray:
    """``n`` values spanning the spec's bounds (geometric when searched on a log scale); for a signed
    effect ``ceil(n / 2)`` geometric magnitudes of each sign and no 0 (0 is the effect's absence); for a
    categorical one the index of every choice, whatever ``n`` (one value, 0, for an effect read off the data)."""
    if spec.categorical:
        return np.arange(max(len(spec.choices), 1), dtype=np.float64)
    lo, hi = spec.bounds
    if spec.signed:
        top = max(abs(lo), abs(hi))
        half = np.geomspace(top / SIGNED_SPAN, top, (n + 1) // 2)
        return np.concatenate([-half[::-1], half])
    return np.geomspace(lo, hi, n) if spec.log_search else np.linspace(lo, hi, n)
