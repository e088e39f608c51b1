"""A simulated effect put on top of real frames (``make-measured --on BAG``), as the thesis'
paper 4 inserts simulated objects into real spray frames.

Every frame of the recording is re-simulated from its recorded poses twice with the same
draws (:class:`~lidar_weather_sim.gap.resim.Resimulator`): with the scenario alone and with the
effects. Then, per beam (channel and azimuth column of the profile):

- returns the effects create (weather, cover, spray and noise labels in the effect run)
  are added to the real frame;
- real returns of beams that return in the scenario run but lose every solid return in
  the effect run (extinction, dirt, a raised noise floor) are removed.

With ``with_actors`` (a recording that lacks the scenario's actors, e.g. a car to throw spray on a real
street) the returns of the scenario's actors in the effect run are added too, and real returns of their
beams that lie behind them are removed (the actor hides them).

Real returns are otherwise kept as they are (intensity, range), so what remains of the
real recording's own reality gap stays in the result. Sensor-family effects (``sensor.intensity_*``,
``range_*``, ``ray_drop``: the unit's response) act on every output point, real or added, as they
act on a simulated frame (:func:`lidar_weather_sim.sensor.response.apply_response`, seeded per frame). The output is a bag like the input:
``/clock``, ``/tf``, ``/tf_static`` copied, and the clouds in the input's point layout.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lidar_weather_sim.core.names import TOPIC_CLOCK, TOPIC_TF, TOPIC_TF_STATIC
from lidar_weather_sim.core.points import SOLID_LABELS, WEATHER_LABELS
from lidar_weather_sim.scenario.effects import Effect, apply_effects
from lidar_weather_sim.gap.resim import Resimulator
from lidar_weather_sim.gap.signatures import beam_keys, nearest_returns
from lidar_weather_sim.io.bags import BagWriter, read_messages
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.regions.base import region_entropy
from lidar_weather_sim.scenario.schema import Scenario
from lidar_weather_sim.sensor.response import apply_response


def augment_frame(real: np.ndarray, base: np.ndarray, effect: np.ndarray, columns: int,
                  actor_ids: tuple[int, ...] = ()) -> np.ndarray:  # fmt: skip
    """``real`` with the returns the effect adds and without those it removes; with the returns of the actors
    ``actor_ids`` (object ids) and without the real returns behind them (see module doc)."""
    solid = np.isin(effect["label"], list(SOLID_LABELS))
    added_mask = np.isin(effect["label"], list(WEATHER_LABELS))
    lost = np.setdiff1d(np.unique(beam_keys(base, columns)), np.unique(beam_keys(effect[solid], columns)))
    kept = real[~np.isin(beam_keys(real, columns), lost)]
    if actor_ids:
        actor = solid & np.isin(effect["object_id"], np.asarray(actor_ids, dtype=np.int64))
        kept = kept[~_behind(kept, effect[actor], columns)]
        added_mask |= actor
    added = effect[added_mask]
    out = np.zeros(len(kept) + len(added), dtype=real.dtype)  # the real layout (offsets, padding) kept
    out[: len(kept)] = kept
    for name in real.dtype.names:
        if name in added.dtype.names:
            out[name][len(kept) :] = added[name]
    return out


def _behind(points: np.ndarray, occluders: np.ndarray, columns: int) -> np.ndarray:
    """Mask of ``points`` on a beam of ``occluders`` and farther than that beam's nearest occluder return."""
    if not len(occluders) or not len(points):
        return np.zeros(len(points), dtype=bool)
    keys, index = nearest_returns(occluders, columns)
    nearest = occluders["distance"][index]
    k = beam_keys(points, columns)
    at = np.clip(np.searchsorted(keys, k), 0, len(keys) - 1)
    return (keys[at] == k) & (points["distance"] > nearest[at])


def augment_recording(path: str | Path, scenario: Scenario, effects: list[Effect], output: str | Path, *,
                      profile: str | None = None, topic: str | None = None, overwrite: bool = False,
                      atmosphere_model: str | None = None, with_actors: bool = False) -> int:  # fmt: skip
    """Write ``path`` with ``effects`` simulated on top of its frames to ``output`` (fog, rain and snow by the
    atmosphere region's ``atmosphere_model``, None: the scenario's; ``with_actors``: the scenario's actors
    too); returns the frames written."""
    recording = Recording.load(path, topic)
    resim = Resimulator(recording, scenario, profile, atmosphere_model=atmosphere_model)
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
            points = augment_frame(frame.points, b, e, columns, actors)
            rng = np.random.default_rng(region_entropy(scenario.seed, k, "sensor_response", 0))
            points = apply_response(points, response, rng, min_range)
            bag.write_cloud(recording.topic, points, frame.stamp_ns, frame.frame_id, log_time_ns=frame.log_time_ns)
    return len(recording.frames)
