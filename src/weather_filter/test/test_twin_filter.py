"""The weather filter as ``lidar-weather-sim twin``'s frame filter (entry point ``lidar_weather_sim.point_filters``)."""

import numpy as np
from numpy.lib import recfunctions as rfn

from lidar_weather_sim.core.points import WEATHER_LABELS
from weather_filter.synthetic import highway_frame
from weather_filter.twin_filter import TwinWeatherFilter, make


def test_keep_mask_and_the_model_that_ran():
    filt = make()
    assert isinstance(filt, TwinWeatherFilter)
    pts = highway_frame("rain", seed=3)
    keep = filt.keep(pts)
    assert keep.dtype == bool and keep.shape == (len(pts),) and filt.name == "learned"  # the EPW model
    weather = np.isin(pts["label"], [int(x) for x in WEATHER_LABELS])
    assert (~keep[weather]).mean() > 0.5 and keep[~weather].mean() > 0.9
    single = rfn.drop_fields(pts, ["epw"], usemask=False)  # a driver without EPW
    filt.reset()
    assert filt.keep(single).shape == (len(single),) and filt.name == "learned-single"
    bare = rfn.drop_fields(pts, ["epw", "intensity"], usemask=False)  # the geometry-only fallback
    filt.keep(bare)
    assert filt.name == "dror"
