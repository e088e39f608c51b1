"""The effects the gap search reads off the recording instead of fitting them (sensor family only).

The calibration frames against their re-simulation without effects and the profile's elevation table:
dead and weak channels, elevation offsets and the beams' origin (:mod:`lidar_weather_sim.gap.channels`), the
near-field ghost rate (:mod:`lidar_weather_sim.gap.ghost`) and the return mode the points' codes name when it is
not the scenario's (:func:`recorded_return_mode`). The search tries them before any fitted effect
(:meth:`lidar_weather_sim.gap.search.GapSearch.read_off_round`).

The return mode a recording was made in is read off its ``return_type`` field.

Drivers that say which return each point is (Nebula's ``ReturnType`` codes, :class:`~lidar_weather_sim.core.points.ReturnType`;
the simulator writes them too, and ``import-ouster`` writes STRONGEST for Ouster's single-return profile) record the
mode with the points: STRONGEST alone is ``strongest``, LAST alone ``last``, FIRST alone ``first``; the dual codes
(STRONGEST with LAST, LAST_STRONGEST, SECOND_STRONGEST) are ``dual``; IDENTICAL, FIRST, SECOND and LAST by a beam's
echo order are ``all``. The point sets of two modes can be the same (``dual`` and ``all`` on a sensor that keeps
two echoes, ``all`` and any single mode where no beam has a second echo), so the codes are the only evidence
there. Without the field, with UNKNOWN codes or with codes no mode gives together: None (the search then tries
each mode).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from lidar_weather_sim.core.points import ReturnType as R
from lidar_weather_sim.gap.channels import MIN_ORIGIN_M, beam_origin, dead_channels, elevation_offsets, weak_channels
from lidar_weather_sim.gap.ghost import cover_returns, ghost_rate
from lidar_weather_sim.gap.signatures import GapResimulator
from lidar_weather_sim.scenario.effects import EFFECTS, Effect, format_channel_values

GHOST_REDRAWS = (1, 2, 3, 4)  # the model draws averaged for each count of the ghost rate read off the data


def read_off_effects(resim: GapResimulator, fit_idx: list[int], keep: Callable[[np.ndarray], np.ndarray] | None,
                     recorded_mode: str | None) -> list[Effect]:  # fmt: skip
    """The effects whose value the calibration frames ``fit_idx`` show (module doc), the points ``keep`` selects
    (None: all); ``recorded_mode``: the return mode the recording's codes name (None: not recorded)."""
    keep = keep or (lambda points: np.ones(len(points), bool))
    measured = [m[keep(m)] for m in (resim.recording.frames[i].points for i in sorted(fit_idx))]
    simulated = [s[keep(s)] for s in resim.frames([], fit_idx)]
    profile, channels = resim.world.profile, resim.channels
    out = []
    dead = dead_channels(measured, simulated, channels)
    if dead:
        out.append(Effect("sensor.dead_channels", {"channels": "+".join(map(str, dead))}))
    weak = weak_channels(measured, simulated, channels, profile.detection.intensity_dynamic_range, profile.scan.columns)
    if weak:
        out.append(Effect("sensor.weak_channels", {"gains": format_channel_values(weak)}))
    nominal = np.array([b.elevation_deg for b in profile.beams])[profile.channel_order]
    offsets = elevation_offsets(measured, nominal)
    if offsets:
        out.append(Effect("sensor.elevation_offsets", {"offsets": format_channel_values(offsets)}))
    if recorded_mode is not None and recorded_mode != (resim.scenario.sensor.return_mode or profile.detection.return_mode):
        out.append(Effect("sensor.return_mode", {"mode": recorded_mode}))
    up, radial = beam_origin(measured, nominal)
    if abs(up) >= MIN_ORIGIN_M:
        out.append(Effect("sensor.beam_origin", {"z": up}))
    if radial >= MIN_ORIGIN_M:
        out.append(Effect("sensor.beam_origin_radial", {"radius": radial}))
    ghost = EFFECTS["sensor.near_field_ghost"]

    def expected(rate: float) -> float:  # the model's cover-zone count at ``rate``, mean over the draws
        effects = [Effect(ghost.name, {ghost.main: rate})]
        return float(np.mean([cover_returns([f[keep(f)] for f in resim.frames(effects, fit_idx, redraw=d)])
                              for d in GHOST_REDRAWS]))  # fmt: skip

    recorded, without = cover_returns(measured), cover_returns(simulated)
    rate = ghost_rate(recorded, without, expected, ghost.bounds, len(GHOST_REDRAWS))
    if rate is not None:
        out.append(Effect(ghost.name, {ghost.main: rate}))
    return out


_SINGLE = {frozenset({R.STRONGEST}): "strongest", frozenset({R.LAST}): "last", frozenset({R.FIRST}): "first"}
_DUAL = frozenset({R.LAST, R.STRONGEST, R.LAST_STRONGEST, R.SECOND_STRONGEST, R.IDENTICAL})
_DUAL_ONLY = frozenset({R.STRONGEST, R.LAST_STRONGEST, R.SECOND_STRONGEST})
_ALL = frozenset({R.IDENTICAL, R.FIRST, R.SECOND, R.LAST})
_ALL_ONLY = frozenset({R.IDENTICAL, R.FIRST, R.SECOND})


def recorded_return_mode(frames: list[np.ndarray]) -> str | None:
    """The return mode whose codes the ``return_type`` fields of ``frames`` hold (module doc), else None."""
    if not frames or any("return_type" not in f.dtype.names for f in frames):
        return None
    codes = frozenset(int(c) for c in np.unique(np.concatenate([f["return_type"] for f in frames])))
    if not codes:
        return None
    if codes in _SINGLE:
        return _SINGLE[codes]
    if codes <= _DUAL and codes & _DUAL_ONLY and (R.LAST in codes or R.LAST_STRONGEST in codes):
        return "dual"
    if codes <= _ALL and codes & _ALL_ONLY:
        return "all"
    return None
