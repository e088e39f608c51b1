"""How well a twin re-simulates the part of its recording it was not built from.

The recording's held-out part (frames, or the held-out sectors' points of every frame; see
:mod:`lidar_weather_sim.gap.split`) is cast again from its recorded poses with the twin's scenario
(:class:`~lidar_weather_sim.gap.signatures.GapResimulator`, no effects) and compared with the measured held-out
points on the bird's-eye occupancy (:func:`lidar_weather_sim.gap.compare.bev_metrics`: Pearson of the
0.5 m cell counts, Jaccard and Hamming distances of the occupied cells) and the point counts.
"""

from __future__ import annotations

from lidar_weather_sim.gap.compare import bev_metrics
from lidar_weather_sim.gap.signatures import GapResimulator, measured_signature
from lidar_weather_sim.gap.split import DataSplit
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.scenario.schema import Scenario


def heldout_resimulation(recording: Recording, scenario: Scenario, split: DataSplit, part: str = "heldout") -> dict:
    """Bird's-eye metrics and point counts of ``part`` of the split, measured vs re-simulated."""
    resim = GapResimulator(recording, scenario)
    frames = split.frames(part)

    def keep(points):
        return split.keep(points, part)

    measured = measured_signature(recording, frames, resim.contexts, resim.channels, keep)
    simulated = resim.signature([], frames, keep)
    counts = {"measured_points": int(sum(int(keep(recording.frames[i].points).sum()) for i in frames))}
    counts["simulated_points"] = int(sum(int(keep(p).sum()) for p in resim.frames([], frames)))
    return {**bev_metrics(measured, simulated), **counts, "frames": list(frames)}
