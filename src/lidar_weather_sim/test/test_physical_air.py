"""The physical atmosphere (regions.physical_air) on hand-made ray batches: seeded, in front of each hit,
the drop counts the beam volume predicts, the volume return where the medium is dense enough."""

from __future__ import annotations

import numpy as np
import pytest

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.physics.coefficients import medium
from lidar_weather_sim.regions.base import RayBatch
from lidar_weather_sim.regions.physical_air import PhysicalAir
from lidar_weather_sim.sensor.profile import load_profile


def batch(hits: np.ndarray, subrays: int = 3) -> RayBatch:
    n = len(hits)
    d = np.zeros((n, subrays, 3))
    d[..., 0] = 1.0
    return RayBatch(frame_index=0, origins=np.zeros((n, 3)), directions=d, sensor_directions=d.copy(),
                    channel=np.zeros(n, np.int64), time_s=np.zeros(n), weights=np.full(subrays, 1.0 / subrays),
                    distance=np.repeat(hits[:, None], subrays, axis=1), normal=np.zeros((n, subrays, 3)),
                    material=np.zeros((n, subrays), np.int64), object_id=np.zeros((n, subrays), np.uint32),
                    label=np.zeros((n, subrays), np.uint8))  # fmt: skip


def test_extinction_is_the_media_at_the_profiles_wavelength():
    os1 = load_profile("os1_128_2048")  # 865 nm
    air = PhysicalAir(os1, 80.0, ("rain", 5.0))
    assert air.alpha == pytest.approx(medium("fog", 80.0, 865.0).alpha + medium("rain", 5.0, 865.0).alpha)


def test_rain_drops_are_seeded_in_front_of_the_hit_and_as_many_as_the_beam_volume_holds():
    air = PhysicalAir(load_profile("scala4"), None, ("rain", 10.0))
    hits = np.where(np.arange(4000) % 2 == 0, 8.0, np.inf)
    a = air.scatterers(batch(hits), np.random.default_rng(3))
    b = air.scatterers(batch(hits), np.random.default_rng(3))
    np.testing.assert_array_equal(a.range_m, b.range_m)
    drops = (a.label == Label.RAIN) & (a.occlusion > 0)  # the volume pulses of the small drops block nothing
    assert (a.range_m[drops] < hits[a.beam[drops]]).all()
    # the drops placed one by one in front of an 8 m hit: the table's expectation, thinned by the overlap
    r = np.linspace(0.05, 8.0, 4000)
    per_m = np.gradient(np.interp(r, air._grid, air._cum), r)
    expected = np.sum(per_m * air.volume.overlap(r)) * (r[1] - r[0])
    placed = np.sum(drops & (hits[a.beam] == 8.0) & (a.range_m < 8.0)) / 2000
    assert placed == pytest.approx(expected, rel=0.05)
    assert a.reflectance[drops].min() > 0 and np.median(a.occlusion[drops]) < 0.01  # a drop blocks little light


def test_fog_gives_every_beam_its_volume_return_up_to_the_hit():
    air = PhysicalAir(load_profile("scala4"), 50.0, None)
    out = air.scatterers(batch(np.array([3.0, 40.0, np.inf])), np.random.default_rng(0))
    assert set(out.label) == {Label.FOG} and out.bypass_overlap.all() and not out.occlusion.any()
    per_beam = np.bincount(out.beam, minlength=3)
    assert 0 < per_beam[0] < per_beam[1] <= per_beam[2]
    assert out.range_m[out.beam == 0].max() < 3.0
    # haze: the same slabs, each as strong as its backscatter (beta) is
    haze = PhysicalAir(load_profile("scala4"), 5000.0, None).scatterers(batch(np.array([40.0])), np.random.default_rng(0))
    fog = out.beam == 1
    common = np.isin(out.range_m[fog], haze.range_m)
    ratio = haze.reflectance[np.isin(haze.range_m, out.range_m[fog])] / out.reflectance[fog][common]
    np.testing.assert_allclose(ratio, medium("fog", 5000.0, 905.0).beta / medium("fog", 50.0, 905.0).beta, rtol=1e-9)
