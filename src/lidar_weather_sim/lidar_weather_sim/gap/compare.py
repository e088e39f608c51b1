"""``lidar-weather-sim compare``: how a simulated recording differs from a measured one, per zone.

Frames are paired by header stamp (nearest, within half a scan period of the measured
rate) or, when no stamps match, by index. Both sides are zoned with the measured
recording's context (road level, vehicles from its ``actor_<id>`` frames;
:mod:`lidar_weather_sim.gap.signatures`). ``metrics.json`` holds:

- ``gap`` and ``gap_terms``: the scalar of :func:`~lidar_weather_sim.gap.signatures.gap_value`
  and its terms (systematic Bray-Curtis of every zone's histograms);
- ``zones``: detections per frame (mean, sd) on each side and the Bray-Curtis of the
  zone's range, intensity and EPW histograms;
- ``bev``: bird's-eye histograms with 0.5 m cells as in the thesis: Pearson correlation
  of the mean counts, Jaccard and Hamming distances of the occupancy (a cell is occupied
  when it holds at least 0.1 returns per frame on average);
- ``near_field_parameters``: the 12 per-frame parameters of paper 2 over 0.5-5 m, each
  compared by the 1-Wasserstein distance of their per-frame distributions, also divided
  by the pooled standard deviation;
- ``echo_histogram`` (returns per frame by echo number), ``epw_histogram`` (0.1 m bins),
  ``returns_by_channel`` and ``returns_by_range`` (returns per frame: ray drop shows as a
  ratio below 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import wasserstein_distance

from lidar_weather_sim.core.frame_parameters import FEATURES
from lidar_weather_sim.gap.signatures import (
    ECHOES,
    EPW_EDGES,
    RANGE_CLASS_EDGES,
    ZONES,
    Signature,
    bray_curtis,
    channel_count,
    frame_contexts,
    gap_terms,
    gap_value,
)
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.scenario.schema import Scenario

OCCUPIED_PER_FRAME = 0.1


@dataclass
class Comparison:
    measured: Signature
    simulated: Signature
    pairs: list[tuple[int, int]]
    paired_by: str


def pair_frames(measured: Recording, simulated: Recording) -> tuple[list[tuple[int, int]], str]:
    """(measured index, simulated index) pairs by stamp, else by index."""
    ms = np.array([f.stamp_ns for f in measured.frames], dtype=np.int64)
    ss = np.array([f.stamp_ns for f in simulated.frames], dtype=np.int64)
    period = np.median(np.diff(ms)) if len(ms) > 1 else 1e8
    j = np.clip(np.searchsorted(ss, ms), 0, len(ss) - 1)
    j_prev = np.clip(j - 1, 0, len(ss) - 1)
    j = np.where(np.abs(ss[j_prev] - ms) < np.abs(ss[j] - ms), j_prev, j)
    ok = np.abs(ss[j] - ms) <= 0.5 * period
    if ok.any():
        return [(int(i), int(k)) for i, k in zip(np.flatnonzero(ok), j[ok])], "time"
    n = min(len(ms), len(ss))
    return [(i, i) for i in range(n)], "index"


def build_comparison(measured: Recording, simulated: Recording, scenario: Scenario | None = None) -> Comparison:
    pairs, how = pair_frames(measured, simulated)
    contexts = frame_contexts(measured, scenario)
    channels = max(channel_count(measured), channel_count(simulated))
    m_sig, s_sig = Signature(channels), Signature(channels)
    for i, k in pairs:
        m_sig.add(measured.frames[i].points, contexts[i])
        s_sig.add(simulated.frames[k].points, contexts[i])
    return Comparison(m_sig, s_sig, pairs, how)


def bev_metrics(measured: Signature, simulated: Signature) -> dict[str, float]:
    a, b = measured.mean("bev").ravel(), simulated.mean("bev").ravel()
    pearson = float(np.corrcoef(a, b)[0, 1]) if a.std() > 0 and b.std() > 0 else float("nan")
    oa, ob = a >= OCCUPIED_PER_FRAME, b >= OCCUPIED_PER_FRAME
    union = int(np.count_nonzero(oa | ob))
    jaccard = 1.0 - np.count_nonzero(oa & ob) / union if union else 0.0
    return {"pearson": pearson, "jaccard_distance": float(jaccard),
            "hamming_distance": float(np.count_nonzero(oa != ob) / len(oa))}  # fmt: skip


def _per_echo(sig: Signature, kind: str) -> np.ndarray:
    """(echoes, bins) mean per frame of the zone histograms of ``kind``, summed over zones."""
    return sum(sig.mean(f"{z}/{kind}").reshape(ECHOES, -1) for z in ZONES)


def _pair(a, b) -> dict[str, list[float]]:
    return {"measured": np.round(np.asarray(a, float), 6).tolist(), "simulated": np.round(np.asarray(b, float), 6).tolist()}


def metrics(c: Comparison) -> dict:
    m, s = c.measured, c.simulated
    out: dict = {
        "frames": {"paired": len(c.pairs), "paired_by": c.paired_by},
        "gap": gap_value(m, s),
        "gap_terms": gap_terms(m, s),
        "zones": {},
        "bev": bev_metrics(m, s),
    }
    md, sd = m.detections(), s.detections()
    for k, zone in enumerate(ZONES):
        entry = {"detections_per_frame": {"measured": [float(md[:, k].mean()), float(md[:, k].std())],
                                          "simulated": [float(sd[:, k].mean()), float(sd[:, k].std())]}}  # fmt: skip
        for kind in ("range", "intensity", "epw"):
            key = f"{zone}/{kind}"
            if key in m.sums and key in s.sums:
                entry[f"{kind}_bray_curtis"] = bray_curtis(m.mean(key), s.mean(key))
        out["zones"][zone] = entry
    mf, sf = m.feature_table(), s.feature_table()
    near = {}
    for name in FEATURES:
        a, b = mf[name][np.isfinite(mf[name])], sf[name][np.isfinite(sf[name])]
        if not len(a) or not len(b):
            near[name] = {"measured_mean": None, "simulated_mean": None, "wasserstein": None, "normalised": None}
            continue
        w = float(wasserstein_distance(a, b))
        pooled = float(np.sqrt(0.5 * (a.var() + b.var())))
        near[name] = {"measured_mean": float(a.mean()), "simulated_mean": float(b.mean()), "wasserstein": w,
                      "normalised": w / pooled if pooled > 0 else (0.0 if w == 0 else None)}  # fmt: skip
    out["near_field_parameters"] = near
    out["echo_histogram"] = _pair(_per_echo(m, "intensity").sum(axis=1), _per_echo(s, "intensity").sum(axis=1))
    if m.has_epw and s.has_epw:
        out["epw_histogram"] = {"edges_m": EPW_EDGES.tolist(),
                                **_pair(_per_echo(m, "epw").sum(axis=0), _per_echo(s, "epw").sum(axis=0))}  # fmt: skip
    n_classes = len(RANGE_CLASS_EDGES) - 1
    mc, sc = m.mean("channel_range").reshape(-1, n_classes), s.mean("channel_range").reshape(-1, n_classes)
    out["returns_by_channel"] = _pair(mc.sum(axis=1), sc.sum(axis=1))
    out["returns_by_range"] = {"edges_m": [float(e) for e in RANGE_CLASS_EDGES[:-1]] + ["inf"],
                               **_pair(mc.sum(axis=0), sc.sum(axis=0))}  # fmt: skip
    return out
