"""The return mode a recording was made in, read off its ``return_type`` field.

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

import numpy as np

from lidar_weather_sim.core.points import ReturnType as R

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
