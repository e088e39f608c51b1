"""A simulated effect put on top of real frames (``make-measured --on BAG``,
:func:`lidar_weather_sim.augment.command.augment_recording`), as the thesis' paper 4 inserts simulated objects
into real spray frames.

Every frame of the recording is re-simulated from its recorded poses twice with the same
draws (:class:`~lidar_weather_sim.replay.Resimulator`): with the scenario alone and with the
effects. Then, per beam (channel and azimuth column of the profile):

- returns the effects create (weather, cover, spray and noise labels in the effect run)
  are added to the real frame;
- real returns of beams that return in the scenario run but lose every solid return in
  the effect run (extinction, dirt, a raised noise floor) are removed.

With ``with_actors`` (a recording that lacks the scenario's actors, e.g. a car to throw spray on a real
street) the returns of the scenario's actors in the effect run are added too, and real returns of their
beams that lie behind them are removed (the actor hides them).

With a weather generator other than the simulator (``make-measured --on BAG --reference`` or ``--generator G``,
:func:`through_generator`), the generator's weather goes on the merged frame: it takes each beam's returns as its
clear scene (real returns as label UNKNOWN), and what it writes comes back in the recording's layout.

Real returns are otherwise kept as they are (intensity, range), so what remains of the
real recording's own reality gap stays in the result. Sensor-family effects (``sensor.intensity_*``,
``range_*``, ``ray_drop``: the unit's response) act on every output point, real or added, as they
act on a simulated frame (:func:`lidar_weather_sim.sensor.response.apply_response`, seeded per frame). The output is a bag like the input:
``/clock``, ``/tf``, ``/tf_static`` copied, and the clouds in the input's point layout.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from lidar_weather_sim.core.points import SOLID_LABELS, WEATHER_LABELS, empty_points
from lidar_weather_sim.replay import beam_keys, nearest_returns
from lidar_weather_sim.sim.simulator import Frame


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


def through_generator(points: np.ndarray, transform: Callable[[Frame], np.ndarray], index: int) -> np.ndarray:
    """``points`` (frame ``index`` of a recording, its layout) in a weather generator's weather: ``transform``
    (:func:`lidar_weather_sim.references.measured.weather_transform`) takes and gives the project's layout with
    ground truth; the recording's returns enter with label UNKNOWN (a real scene) and, where the layout has none,
    EPW 0 (the generator then reads each return's peak from its intensity alone); the result comes back in
    ``points``' layout (fields it lacks, such as the EPW, left out)."""
    full = empty_points(len(points))
    for name in points.dtype.names:
        if name in full.dtype.names:
            full[name] = points[name]
    made = transform(Frame(index, 0.0, full, 0))
    out = np.zeros(len(made), dtype=points.dtype)
    for name in points.dtype.names:
        if name in made.dtype.names:
            out[name] = made[name]
    return out
