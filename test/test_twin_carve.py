"""A twin's mesh against the beams that built it (twin/carve.py), and a twin's reflectivity read as measured
through the air the gap search puts on it (Scene.recorded_range_m, LidarSimulator.reflectivity_through_air)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from lidar_weather_sim.scenario.effects import apply_effects, parse_effect
from lidar_weather_sim.scenario.schema import Scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.scene.surveyed import REFLECTIVITY_RANGE, write_surveyed_ply
from lidar_weather_sim.sensor.radiometry import dark_level
from lidar_weather_sim.sim.simulator import LidarSimulator
from lidar_weather_sim.testing.fixtures import LinearPose, one_frame, simple_profile
from lidar_weather_sim.twin.carve import CalibrationScan, carve_mesh


def _quad(x0: float, x1: float, y0: float, y1: float, z0: float = -2.0, z1: float = 2.0) -> tuple[np.ndarray, ...]:
    """A vertical rectangle facing the sensor at the origin: from (x0, y0) to (x1, y1), z0..z1 m; two triangles."""
    v = np.array([[x0, y0, z0], [x1, y1, z0], [x0, y0, z1], [x1, y1, z1]], float)
    return v, np.array([[0, 1, 2], [1, 3, 2]])


def _mesh(*quads) -> tuple[np.ndarray, np.ndarray]:
    vertices, triangles = [], []
    for v, t in quads:
        triangles.append(t + sum(len(x) for x in vertices))
        vertices.append(v)
    return np.concatenate(vertices), np.concatenate(triangles)


def _beam_directions(azimuth_deg: np.ndarray) -> np.ndarray:
    """(columns, 1 channel, 1 sub-ray, 3) horizontal unit directions."""
    az = np.radians(azimuth_deg)
    return np.stack([np.cos(az), np.sin(az), np.zeros_like(az)], -1)[:, None, None, :]


def test_the_carve_deletes_what_was_seen_through_darkens_what_never_returned_and_keeps_the_rest():
    """One horizontal channel of 360 columns, a wall at x = 20 m across +-40 deg. The mesh adds a sheet at x = 10 m
    over azimuth 5-15 deg (the recording saw the wall behind it: free space); along the wall at 20-30 deg the
    recording has no returns (a surface too dark to return); at 30-35 deg only fog echoes at 3 m, at 35-40 deg
    a solid return at 3 m (a vehicle the twin left out)."""
    columns = 360
    centres = -180.0 + np.arange(columns) + 0.5
    sheet = _quad(10.0, 10.0, 10.0 * np.tan(np.radians(5)), 10.0 * np.tan(np.radians(15)))
    # the wall split at the marked azimuths so each stretch is its own pair of triangles
    edges = [-40.0, 5.0, 20.0, 30.0, 35.0, 40.0]
    stretches = [_quad(20.0, 20.0, 20.0 * np.tan(np.radians(a)), 20.0 * np.tan(np.radians(b))) for a, b in zip(edges, edges[1:])]
    vertices, triangles = _mesh(*stretches, sheet)
    reflectivity = np.full(len(triangles), 0.3)
    recorded_range = np.full(len(triangles), 20.0)

    seen = (np.abs(centres) < 40.0) & ~((centres > 20.0) & (centres < 30.0))  # the wall's returns the sensor made
    front = (centres > 30.0) & (centres < 40.0)  # the fog echoes and the vehicle, in front of the wall
    az_wall = np.radians(centres[seen & ~front])
    r_wall = 20.0 / np.cos(az_wall)
    az_front = np.radians(centres[front])
    az = np.concatenate([az_wall, az_front])
    r = np.concatenate([r_wall, np.full(len(az_front), 3.0)])
    local = np.stack([r * np.cos(az), r * np.sin(az), np.zeros_like(r)], -1)
    weather = np.concatenate([np.zeros(len(az_wall), bool), centres[front] < 35.0])
    scan = CalibrationScan(local, np.zeros(len(local), np.int64), weather, np.eye(4), 0.0, np.ones(columns, bool),
                           _beam_directions(centres), np.array([0]))  # fmt: skip
    carved = carve_mesh(vertices, triangles, reflectivity, recorded_range, [scan], 1, 2, 200.0)

    assert carved.summary["triangles_deleted"] == 2  # the sheet
    assert len(carved.triangles) == len(triangles) - 2
    kept = carved.reflectivity
    dark = REFLECTIVITY_RANGE[0]
    # stretches in order: -40..5 (seen), 5..20 (seen, behind the sheet), 20..30 (no returns), 30..35 (fog only),
    # 35..40 (behind a vehicle: no vote)
    assert np.all(kept[0:4] == 0.3)
    assert np.all(kept[4:6] == dark) and np.all(kept[6:8] == dark)
    assert np.all(kept[8:10] == 0.3)
    assert np.allclose(carved.recorded_range, 20.0)
    # every triangle's vertices survive the deletion's re-indexing
    assert np.allclose(carved.vertices[carved.triangles], vertices[triangles[:-2]])


def test_a_sensor_with_its_echoes_used_up_in_front_does_not_vote():
    """A single-echo sensor whose only echo is fog at 3 m could not have reported the wall behind it."""
    centres = np.array([0.5])
    vertices, triangles = _mesh(_quad(20.0, 20.0, -1.0, 1.0))
    scan = CalibrationScan(np.array([[3.0, 0.0, 0.0]]), np.zeros(1, np.int64), np.ones(1, bool), np.eye(4), 0.0,
                           np.ones(360, bool), _beam_directions(centres), np.array([0]))  # fmt: skip
    for max_echoes, darkened in ((1, 0), (2, 1)):
        carved = carve_mesh(vertices, triangles, np.full(2, 0.3), np.full(2, 20.0), [scan], 1, max_echoes, 200.0)
        assert carved.summary["triangles_darkened"] == darkened


def _wall_scenario(tmp_path, recorded_range: float | None) -> Scenario:
    profile = simple_profile()
    (tmp_path / "profile.yaml").write_text(yaml.safe_dump(profile.model_dump(mode="json")))
    v, t = _quad(20.0, 20.0, -10.0, 10.0, -5.0, 5.0)
    ranges = None if recorded_range is None else np.full(len(t), recorded_range)
    write_surveyed_ply(tmp_path / "wall.ply", v, t, np.full(len(t), 0.05), ranges)
    return Scenario.model_validate({"name": "wall", "map": None, "static_meshes": [str(tmp_path / "wall.ply")],
                                    "sensor": {"profile": str(tmp_path / "profile.yaml")}})  # fmt: skip


def _wall_intensity(scenario: Scenario, effects: list[str], through_air: bool) -> float:
    world = World.build(apply_effects(scenario, [parse_effect(e) for e in effects]))
    sim = LidarSimulator.of_world(world)
    sim.reflectivity_through_air = through_air
    p = one_frame(sim, LinearPose()).points
    on_wall = np.abs(p["distance"] - 20.0 / np.cos(p["azimuth"])) < 0.5
    assert on_wall.sum() >= 60
    return float(np.mean(p["intensity"][on_wall]))


def test_a_twin_seen_through_fog_loses_the_fog_once(tmp_path):
    """A surveyed wall whose reflectivity was measured from 20 m: under fog, read as measured through that fog,
    it returns what it returned in the recording (the clear-air intensity); read as its own reflectivity, the
    fog dims it by exp(-2 alpha R). A mesh without recorded ranges is dimmed either way."""
    scenario = _wall_scenario(tmp_path, 20.0)
    fog = ["atmosphere.fog:visual_range=150"]
    clear = _wall_intensity(scenario, [], True)
    once = _wall_intensity(scenario, fog, True)
    twice = _wall_intensity(scenario, fog, False)
    world = World.build(apply_effects(scenario, [parse_effect(fog[0])]))
    alpha = dict(world.regions())["atmosphere"].alpha
    det = simple_profile().detection
    lost_bytes = 255.0 * 2.0 * alpha * 20.0 / np.log(det.intensity_dynamic_range)
    assert dark_level(det) > 0 and lost_bytes > 10.0
    assert once == pytest.approx(clear, abs=1.0)
    assert clear - twice == pytest.approx(lost_bytes, abs=2.0)
    (tmp_path / "plain").mkdir()
    plain = _wall_scenario(tmp_path / "plain", None)
    assert _wall_intensity(plain, fog, True) == pytest.approx(twice, abs=1.0)


def test_on_a_twin_the_atmosphere_is_named_by_its_own_echoes():
    """On a twin the far field comes back as recorded with any fog (its reflectivity holds the loss): the fog is
    judged on the near field, which it fills; off a twin the same residuals refuse it (nothing to remove in its
    range zones). A wet road cannot be told from a dark one on a twin."""
    from lidar_weather_sim.gap.unexplained import ZoneResidual, removes_its_residual

    def residuals(near: float, far: float) -> dict[str, ZoneResidual]:
        return {"near": ZoneResidual("near", near, 10.0 if near else 0.0, float("nan"), "excess returns", ()),
                "far": ZoneResidual("far", far, 5.0 if far else 0.0, -0.02, "uniform loss", ()),
                "road": ZoneResidual("road", 0.0, 0.0, 0.0, "no residual", ())}  # fmt: skip

    without, with_fog = residuals(near=90_000.0, far=0.0), residuals(near=1_000.0, far=0.0)
    assert removes_its_residual("atmosphere.fog", without, with_fog, twin=True) is None
    assert "no residual to remove" in removes_its_residual("atmosphere.fog", without, with_fog, twin=False)
    left = residuals(near=30_000.0, far=0.0)
    assert "leaves near field" in removes_its_residual("atmosphere.fog", without, left, twin=True)
    assert "not told apart" in removes_its_residual("atmosphere.road_wet", without, with_fog, twin=True)
    assert removes_its_residual("sensor.range_noise", without, with_fog, twin=True) is None  # no zones
