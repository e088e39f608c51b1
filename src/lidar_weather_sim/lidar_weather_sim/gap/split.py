"""The gap search's frames: a recording's calibration / held-out split, by index or as a file (``split.yaml``, written by ``lidar-weather-sim twin``).

Two kinds:

- ``frames``: whole frames (by their index in the topic, stamp order): even frames calibrate, odd
  frames are held out (:func:`split_frames` without a file splits the frames of each layer of an alternating
  scan pattern so).
- ``sectors``: for recordings with few frames (a single scan works), every frame is used but only
  the points of some azimuth sectors (sensor frame, REP-103: azimuth = atan2(y, x), deg, [lo, hi))
  calibrate; the points of the other sectors are held out. Contiguous sectors of ``sector_deg``
  (default 30 deg) alternate from -180 deg: even sectors calibrate, odd sectors are held out.

``gap`` reads the file beside a scenario (:func:`split_beside`): it then fits on the calibration part
and scores on the held-out part only, so the twin and the gap never use the same points.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import yaml

SPLIT_FILE = "split.yaml"
#: Fewer frames than this get a sector split (a frame split would leave one or two frames per part).
MIN_FRAMES_FOR_FRAME_SPLIT = 4
SECTOR_DEG = 30.0


@dataclass(frozen=True)
class DataSplit:
    kind: Literal["frames", "sectors"]
    calibration_frames: list[int]
    heldout_frames: list[int]
    calibration_sectors_deg: list[tuple[float, float]] = field(default_factory=list)  # sectors kind only
    heldout_sectors_deg: list[tuple[float, float]] = field(default_factory=list)

    def frames(self, part: str) -> list[int]:
        """Frame indices of ``part`` ("calibration" or "heldout")."""
        return self.calibration_frames if part == "calibration" else self.heldout_frames

    def keep(self, points: np.ndarray, part: str) -> np.ndarray:
        """Boolean mask of the points (sensor frame) that belong to ``part``: all of them for a frame split,
        those whose azimuth lies in the part's sectors for a sector split."""
        if self.kind == "frames":
            return np.ones(len(points), dtype=bool)
        sectors = np.radians(self.calibration_sectors_deg if part == "calibration" else self.heldout_sectors_deg)
        az = np.arctan2(points["y"].astype(np.float64), points["x"].astype(np.float64))
        inside = (az[:, None] >= sectors[None, :, 0]) & (az[:, None] < sectors[None, :, 1])
        return inside.any(axis=1)

    def to_dict(self) -> dict:
        out = {"kind": self.kind, "calibration": {"frames": list(self.calibration_frames)},
               "heldout": {"frames": list(self.heldout_frames)}}  # fmt: skip
        if self.kind == "sectors":
            out["calibration"]["sectors_deg"] = [list(map(float, s)) for s in self.calibration_sectors_deg]
            out["heldout"]["sectors_deg"] = [list(map(float, s)) for s in self.heldout_sectors_deg]
        return out

    @classmethod
    def from_dict(cls, data: dict, source: str = "split") -> "DataSplit":
        try:
            kind = data["kind"]
            cal, held = data["calibration"], data["heldout"]
            out = cls(kind, [int(i) for i in cal["frames"]], [int(i) for i in held["frames"]],
                      [tuple(map(float, s)) for s in cal.get("sectors_deg", [])],
                      [tuple(map(float, s)) for s in held.get("sectors_deg", [])])  # fmt: skip
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{source}: not a calibration/held-out split ({type(exc).__name__}: {exc})") from None
        if kind not in ("frames", "sectors") or not out.calibration_frames or not out.heldout_frames:
            raise ValueError(f"{source}: kind must be frames or sectors, with frames in both parts")
        if kind == "sectors" and not (out.calibration_sectors_deg and out.heldout_sectors_deg):
            raise ValueError(f"{source}: a sector split needs sectors_deg in both parts")
        return out

    def write(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text("# calibration / held-out split of the recording (lidar_weather_sim.gap.split)\n"
                        + yaml.safe_dump(self.to_dict(), sort_keys=False))  # fmt: skip
        return path

    @classmethod
    def load(cls, path: str | Path) -> "DataSplit":
        return cls.from_dict(yaml.safe_load(Path(path).read_text()) or {}, str(path))


def split_recording(n_frames: int, kind: str = "auto", sector_deg: float = SECTOR_DEG) -> DataSplit:
    """The split of a recording of ``n_frames`` frames: ``kind`` "frames" (even / odd), "sectors"
    (alternating ``sector_deg`` sectors of every frame) or "auto": frames from
    :data:`MIN_FRAMES_FOR_FRAME_SPLIT` frames on, else sectors."""
    if n_frames < 1:
        raise ValueError("a split needs at least one frame")
    if kind not in ("auto", "frames", "sectors"):
        raise ValueError(f"split kind must be auto, frames or sectors, not {kind!r}")
    count = 360.0 / sector_deg if sector_deg > 0 else 0.0
    if count < 2 or abs(count - round(count)) > 1e-9:
        raise ValueError(f"sector_deg must divide 360 deg into at least 2 sectors, got {sector_deg:g}")
    if kind == "frames" and n_frames < 2:
        raise ValueError("a frame split needs at least 2 frames (one to calibrate, one held out)")
    if kind == "frames" or (kind == "auto" and n_frames >= MIN_FRAMES_FOR_FRAME_SPLIT):
        return DataSplit("frames", list(range(0, n_frames, 2)), list(range(1, n_frames, 2)))
    edges = np.arange(-180.0, 180.0 + 1e-9, sector_deg)
    sectors = [(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:])]
    frames = list(range(n_frames))
    return DataSplit("sectors", frames, frames, sectors[0::2], sectors[1::2])


def split_beside(scenario_file: str | Path) -> DataSplit | None:
    """The split in ``split.yaml`` next to a scenario file (a twin's directory), None if there is none."""
    path = Path(scenario_file).parent / SPLIT_FILE
    return DataSplit.load(path) if path.is_file() else None


def thin_evenly(indices: list[int], budget: int) -> list[int]:
    """At most ``budget`` of ``indices``, evenly spaced."""
    if len(indices) <= budget:
        return list(indices)
    return [indices[int(k)] for k in np.linspace(0, len(indices) - 1, budget).round()]


def split_frames(n: int, fit_frames: int, heldout_frames: int, split: DataSplit | None = None,
                 layers: list[int] | None = None) -> tuple[list[int], list[int]]:
    """Calibration and held-out frame indices, each thinned evenly to its budget: by default even frames calibrate,
    odd frames are held out; on a sensor whose frames alternate their layers (``layers``: each frame's layer, e.g.
    scala4's scan index modulo its 2-entry ``layer_schedule``) the frames of each layer alternate in turn, so both
    parts hold every layer (even / odd frames split scala4 into its channels 0-2 and 1-3: the fit never saw the top
    layer it was judged on). With a ``split`` (a twin's split.yaml), its parts' frames instead (the same frames for a
    sector split)."""
    for name, budget in (("fit_frames", fit_frames), ("heldout_frames", heldout_frames)):
        if budget < 1:
            raise ValueError(f"gap: {name} must be at least 1, got {budget}")
    if split is not None:
        beyond = [i for i in split.calibration_frames + split.heldout_frames if not 0 <= i < n]
        if beyond:
            raise ValueError(f"gap: the split names frames {beyond[:5]} but the recording has {n} frames")
        return thin_evenly(split.calibration_frames, fit_frames), thin_evenly(split.heldout_frames, heldout_frames)
    if n < 2:
        raise ValueError(f"gap needs at least 2 frames with poses (one to fit, one held out), the recording has {n}")
    layer = np.zeros(n, dtype=np.int64) if layers is None else np.asarray(layers, dtype=np.int64)
    if len(layer) != n:
        raise ValueError(f"gap: {len(layer)} frame layers for {n} frames")
    rank = np.zeros(n, dtype=np.int64)  # each frame's place among the frames of its layer
    for value in np.unique(layer):
        rank[layer == value] = np.arange(np.sum(layer == value))
    frames = np.arange(n)
    return (thin_evenly(frames[rank % 2 == 0].tolist(), fit_frames),
            thin_evenly(frames[rank % 2 == 1].tolist(), heldout_frames))  # fmt: skip


def screening_frames(fit_idx: list[int], budget: int, layers: list[int] | None = None) -> list[int]:
    """Up to ``budget`` of the calibration frames ``fit_idx`` for screening: of each layer's (``layers``: every
    recording frame's layer, None: one layer) an equal share, evenly spaced from its first, the layers interleaved."""
    layer = [0] * (max(fit_idx, default=0) + 1) if layers is None else layers
    groups = [[i for i in fit_idx if layer[i] == value] for value in sorted({layer[i] for i in fit_idx})]
    share = -(-max(budget, 1) // max(len(groups), 1))
    picked = [g[:: max(1, len(g) // share)][:share] for g in groups]
    return [i for row in zip(*[p + [None] * (share - len(p)) for p in picked]) for i in row if i is not None][:budget]
