"""``lidar-weather-sim make-measured``: "measured" data with effects hidden in it, for testing ``gap``.

The scenario is run with the hidden effects (:mod:`lidar_weather_sim.scenario.effects`) plus
nuisance that no effect of the model explains, so that a perfect diagnosis still leaves a
residual gap:

- another seed than the scenario's (default: the scenario's seed + 1000);
- extra range noise: Gaussian, ``extra_range_noise_m`` (default 0.02 m) along the beam (the
  model has one way to explain it: the lightest thesis dirt sample, 1u at T 0.995, raises the
  range sigma by 26.7 %; ``gap`` may name ``cover.dirt`` near 0.995 for it);
- dropped frames: each frame is lost with probability ``drop_fraction`` (default 0.02).

The bag looks like a real recording: ``/clock``, ``/tf``, ``/tf_static`` and the cloud
topic only, and points without ``label`` and ``object_id`` (the 40-byte layout; ``ground_truth=True``,
``make-measured --labels``, keeps them: weather points then carry FOG / RAIN / SNOW).

``generator`` says who makes the weather:

- ``fast`` (default): the project's own effects (:mod:`lidar_weather_sim.scenario.effects`) in the simulator;
- ``reference``: fog, rain and snow by the independent drop-by-drop reference
  (:mod:`lidar_weather_sim.references.droplets`) on the simulator's clear frames; the other effects (sun, cover,
  spray, road) by the simulator, and the weather's own returns through the cover's transmission
  (:func:`cover_two_way`);
- ``hahner``: fog by the simplified extinction-plus-soft-echo generator (:mod:`lidar_weather_sim.references.hahner`,
  after Hahner et al., ICCV 2021) on the clear frames; other effects by the simulator (no rain or snow);
- ``fog_loss``, ``fog_spread``, ``fog_shell`` (fog) and ``precip_dsd`` (rain or snow): the generators fixed before
  use (:mod:`lidar_weather_sim.references.generators`) on the clear frames, with ``cover.dirt`` as their own
  dirty cover (a two-way transmission on every return, after the weather); they take no other effect.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from lidar_weather_sim.core.points import add_range_noise, strip_ground_truth
from lidar_weather_sim.scenario.effects import Effect, apply_effects
from lidar_weather_sim.scenario.schema import Scenario
from lidar_weather_sim.sim.offline import RunReport, run_scenario
from lidar_weather_sim.sim.simulator import Frame


@dataclass(frozen=True)
class Nuisance:
    """What the measurement adds beyond the model (see module doc)."""

    seed_offset: int = 1000
    extra_range_noise_m: float = 0.02
    drop_fraction: float = 0.02


GENERATORS = ("fast", "reference", "hahner", "fog_loss", "fog_spread", "fog_shell", "precip_dsd")
#: the effects each fixed generator makes (besides ``cover.dirt``)
FIXED_WEATHER = {"fog_loss": ("atmosphere.fog",), "fog_spread": ("atmosphere.fog",),
                 "fog_shell": ("atmosphere.fog",), "precip_dsd": ("atmosphere.rain", "atmosphere.snow")}


def made_by(generator: str) -> tuple[str, ...]:
    """The effects ``generator`` makes itself (the simulator makes the others): none for ``fast``."""
    if generator in FIXED_WEATHER:
        return FIXED_WEATHER[generator] + ("cover.dirt",)
    from lidar_weather_sim.references.droplets import ATMOSPHERE_EFFECTS

    return ATMOSPHERE_EFFECTS if generator in ("reference", "hahner") else ()


def degrade(points: np.ndarray, sigma_m: float, rng: np.random.Generator, ground_truth: bool = False) -> np.ndarray:
    """Points (without ground truth unless ``ground_truth``), each moved along its beam by N(0, sigma_m) (m)."""
    out = points.copy() if ground_truth else strip_ground_truth(points)
    add_range_noise(out, sigma_m, rng)
    return out


def cover_two_way(scenario: Scenario, profile) -> np.ndarray | None:
    """(columns, channels) two-way transmission of each beam through the scenario's sensor cover, as its
    ``cover`` region draws it; None without that region."""
    if "cover" not in scenario.regions:
        return None
    from lidar_weather_sim.regions.base import RegionContext
    from lidar_weather_sim.regions.cover import CoverParams, CoverRegion

    params = CoverParams.model_validate(scenario.region_params.get("cover", {}))
    return CoverRegion(params, RegionContext(profile=profile)).beam_two_way()


def weather_transform(scenario: Scenario, effects: list[Effect], generator: str, profile: str | None,
                      seed: int, beams_per_frame: int | None = None):  # fmt: skip
    """(scenario with the effects the simulator makes, ``transform(frame) -> points`` or None) of ``generator``."""
    if generator == "fast":
        return apply_effects(scenario, effects), None
    if generator not in GENERATORS:
        raise ValueError(f"generator {generator!r}: one of {', '.join(GENERATORS)}")
    from lidar_weather_sim.references.droplets import Atmosphere
    from lidar_weather_sim.sensor.profile import load_profile

    if generator in FIXED_WEATHER:
        prof = load_profile(profile or scenario.sensor.profile)
        if scenario.sensor.return_mode:
            prof = prof.with_return_mode(scenario.sensor.return_mode)
        return scenario, fixed_transform(effects, generator, prof, np.random.default_rng([seed & 0xFFFFFFFF, 0x666978]))
    atmosphere, rest = Atmosphere.split(effects)
    hidden = apply_effects(scenario, rest)
    prof = load_profile(profile or scenario.sensor.profile)
    if scenario.sensor.return_mode:
        prof = prof.with_return_mode(scenario.sensor.return_mode)
    sun = float(hidden.weather.sun.irradiance_w_m2)
    rng = np.random.default_rng([seed & 0xFFFFFFFF, 0x726566])  # "ref": the generator's own stream
    if generator == "reference":
        from lidar_weather_sim.references.droplets import ReferenceAtmosphere

        if prof.detection.return_mode != "all":
            raise ValueError(f"the atmosphere reference reports every echo (return mode all), not "
                             f"{prof.detection.return_mode!r}")  # fmt: skip
        ref = ReferenceAtmosphere(prof, atmosphere, sun_irradiance_w_m2=sun, beams_per_frame=beams_per_frame,
                                  cover_two_way=cover_two_way(hidden, prof))  # fmt: skip
        return hidden, lambda frame: ref.apply(frame.points, frame.index, rng)
    from lidar_weather_sim.references.hahner import HahnerFog

    if atmosphere.precipitation is not None:
        raise ValueError("the hahner generator makes fog only (Hahner et al. 2021): no atmosphere.rain or .snow")
    if atmosphere.fog_m is None:
        return hidden, None
    fog = HahnerFog(prof, atmosphere.fog_m, sun_irradiance_w_m2=sun)
    return hidden, lambda frame: fog.apply(frame.points, rng)


def fixed_transform(effects: list[Effect], generator: str, profile, rng: np.random.Generator):
    """``transform(frame) -> points`` of the fixed ``generator`` on ``profile``'s clouds: its weather, then
    ``cover.dirt`` as its own dirty cover; None when ``effects`` is empty. Each frame draws from ``rng``."""
    from lidar_weather_sim.references.generators.cover import DirtyCover
    from lidar_weather_sim.references.generators.echoes import Receiver
    from lidar_weather_sim.references.generators.fog_loss import FogLoss
    from lidar_weather_sim.references.generators.fog_shell import FogShell
    from lidar_weather_sim.references.generators.fog_spread import FogSpread
    from lidar_weather_sim.references.generators.precip_dsd import PrecipDSD

    made = FIXED_WEATHER[generator] + ("cover.dirt",)
    other = [e.label() for e in effects if e.name not in made]
    if other or len({e.name.split(".")[0] for e in effects}) < len(effects):
        raise ValueError(f"the {generator} generator makes one of {', '.join(made[:-1])} and cover.dirt, not "
                         f"{', '.join(e.label() for e in effects)}")  # fmt: skip
    rx = Receiver.of(profile)
    steps = []
    for e in effects:
        if e.name == "cover.dirt":
            continue
        kind = e.name.split(".")[1]
        steps.append(PrecipDSD(rx, kind, e.value) if generator == "precip_dsd" else
                     {"fog_loss": FogLoss, "fog_spread": FogSpread, "fog_shell": FogShell}[generator](rx, e.value))
    steps += [DirtyCover(rx, e.value) for e in effects if e.name == "cover.dirt"]
    if not steps:
        return None

    def transform(frame: Frame) -> np.ndarray:
        points = frame.points
        for step in steps:
            points = step.apply(points, rng)
        return points

    return transform


def make_measured(
    scenario: Scenario,
    effects: list[Effect],
    output: str | Path,
    *,
    frames: int | None = None,
    seed: int | None = None,
    profile: str | None = None,
    nuisance: Nuisance = Nuisance(),
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
    generator: str = "fast",
    ground_truth: bool = False,
    beams_per_frame: int | None = None,
) -> RunReport:
    """Record ``scenario`` with ``effects`` hidden in it by ``generator`` (see module doc) and ``nuisance`` added
    to ``output``; ``beams_per_frame``: the reference's sampled beams (default: all of a small profile)."""
    run_seed = scenario.seed + nuisance.seed_offset if seed is None else seed
    hidden, transform = weather_transform(scenario, effects, generator, profile, run_seed, beams_per_frame)
    rng = np.random.default_rng([run_seed & 0xFFFFFFFF, 0x6D6561])  # "mea": the nuisance's own stream

    def measure(frame: Frame) -> np.ndarray | None:
        if rng.random() < nuisance.drop_fraction:
            return None
        points = frame.points if transform is None else transform(frame)
        return degrade(points, nuisance.extra_range_noise_m, rng, ground_truth)

    return run_scenario(hidden, output, frames=frames, seed=run_seed, profile=profile, overwrite=overwrite,
                        progress=progress, postprocess=measure)  # fmt: skip


#: Reference diagnoses (each effect alone and two pairs) checked by test/test_gap.py and
#: printed by benchmarks/validation/gap_recovery.py, on highway_clear.
RECOVERY_CASES = [
    ["atmosphere.fog:visual_range=80"],
    ["atmosphere.rain:intensity=10"],
    ["atmosphere.snow:intensity=1.5"],
    ["atmosphere.road_wet:water_film=1.5"],
    ["cover.dirt:transmission=0.7"],
    ["cover.water:transmission=0.8"],
    ["sensor.sun:irradiance=400"],
    ["spray:water_film=1.0,actor=100"],
    ["atmosphere.fog:visual_range=80", "sensor.sun:irradiance=400"],
    ["cover.dirt:transmission=0.7", "spray:water_film=1.0,actor=100"],
]


def case_scenario(base: Scenario, hidden: list[str]) -> Scenario:
    """``base`` for a recovery case: the scala4 at bumper height, level, sees almost no road, so
    a hidden road effect is measured with the sensor pitched 3 deg down (road in view)."""
    if not any(h.startswith("atmosphere.road_wet") for h in hidden):
        return base
    mount = base.sensor.mount.model_copy(update={"pitch_deg": 3.0})
    return base.model_copy(update={"sensor": base.sensor.model_copy(update={"mount": mount})})
