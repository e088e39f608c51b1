"""The augmentation's entry points, as the command line calls them: synthetic weather on a recording
(``make-measured --on BAG``, :func:`augment_recording`; the per-beam merge in :mod:`.weather`) and paper 4's
synthetic obstacles (``augment``, :func:`augment_obstacles`; :mod:`.obstacles`)."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from lidar_weather_sim.augment.kinds import parse_kinds
from lidar_weather_sim.augment.obstacles import AugmentSummary, augment_bag, check_profile, profile_for_cloud
from lidar_weather_sim.augment.weather import augment_frame, through_generator
from lidar_weather_sim.core.names import TOPIC_CLOCK, TOPIC_TF, TOPIC_TF_STATIC
from lidar_weather_sim.io.bags import BagWriter, read_messages
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.regions.base import region_entropy
from lidar_weather_sim.replay import Resimulator
from lidar_weather_sim.scenario.effects import Effect, apply_effects
from lidar_weather_sim.scenario.schema import Scenario
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.sensor.radiometry import reflectivity_intensity
from lidar_weather_sim.sensor.response import apply_response
from lidar_weather_sim.sim.simulator import Frame


def augment_recording(path: str | Path, scenario: Scenario, effects: list[Effect], output: str | Path, *,
                      profile: str | None = None, topic: str | None = None, overwrite: bool = False,
                      with_actors: bool = False, transform: Callable[[Frame], np.ndarray] | None = None,
                      reflectivity: bool = False) -> int:  # fmt: skip
    """Write ``path`` with ``effects`` simulated on top of its frames to ``output`` (``with_actors``: the
    scenario's actors too); returns the frames written. ``transform``: a weather generator's frame transform
    (``make-measured --on --reference`` or ``--generator G``, which the command line takes from
    :func:`lidar_weather_sim.references.measured.weather_transform`; the effects it makes are then not in
    ``effects``), run on every merged frame (:func:`.weather.through_generator`).
    ``reflectivity``: the recording's intensity is a calibrated reflectivity (percent), turned into the profile's
    intensity scale first (:func:`~lidar_weather_sim.sensor.radiometry.reflectivity_intensity`), so that a loss
    dims each real return by its own signal; the output holds the profile's scale."""
    recording = Recording.load(path, topic)
    resim = Resimulator(recording, scenario, profile)
    columns = resim.world.profile.scan.columns
    everything = range(len(recording.frames))
    weather = [e for e in effects if e.spec.family != "sensor"]
    response = apply_effects(scenario, [e for e in effects if e.spec.family == "sensor"]).sensor.response
    base = resim.frames([], everything)
    with_effects = resim.frames(weather, everything) if weather else base
    min_range = float(resim.world.profile.range.min_m)
    actors = tuple(a.id for a in scenario.actors) if with_actors else ()
    with BagWriter(output, overwrite=overwrite) as bag:
        for m in read_messages(path, [TOPIC_CLOCK, TOPIC_TF, TOPIC_TF_STATIC]):
            bag.write(m.topic, m.msg, m.log_time_ns)
        for k, (frame, b, e) in enumerate(zip(recording.frames, base, with_effects)):
            real = frame.points
            if reflectivity:
                real = real.copy()
                real["intensity"] = reflectivity_intensity(real["intensity"], real["distance"], resim.world.profile)
            points = augment_frame(real, b, e, columns, actors)
            if transform is not None:
                points = through_generator(points, transform, k)
            rng = np.random.default_rng(region_entropy(scenario.seed, k, "sensor_response", 0))
            points = apply_response(points, response, rng, min_range)
            bag.write_cloud(recording.topic, points, frame.stamp_ns, frame.frame_id, log_time_ns=frame.log_time_ns)
    return len(recording.frames)


def augment_obstacles(bag: str | Path, out: str | Path, *, profile: str | None = None, topic: str | None = None,
                      objects: int = 1, sizes_m: tuple[float, float] | None = None, kinds: str = "box",
                      epw_match: str = "lead", seed: int = 0,
                      overwrite: bool = False) -> tuple[AugmentSummary, str, tuple[str, ...]]:  # fmt: skip
    """Write ``bag`` with ``objects`` synthetic obstacles per frame to ``out`` (:func:`augment_bag`): ``kinds`` as
    ``box,vehicle,...``, ``profile`` the cloud's sensor profile (None: the shipped one that matches its first
    frame, checked against it either way). Returns what was done, the profile's name and the kinds."""
    parsed = parse_kinds(kinds)
    first = Recording.load(bag, topic).frames[0].points
    name = profile or profile_for_cloud(first)
    loaded = load_profile(name)
    check_profile(first, loaded, name)
    done = augment_bag(bag, out, loaded, name, topic=topic, objects=objects, size_m=sizes_m, seed=seed,
                       overwrite=overwrite, kinds=parsed, epw_match=epw_match)  # fmt: skip
    return done, name, parsed
