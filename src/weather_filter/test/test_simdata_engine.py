"""The training runs simulated on two Dask worker processes are the runs simulated one after another."""

from __future__ import annotations

import numpy as np
import pytest

from weather_filter.simdata import frames_of, simulate_all

SPECS = ["highway_spray:7:3", "wf_train_fog:7:2:vlp16", "wf_train_snow:7:2"]


@pytest.mark.slow
def test_two_workers_make_the_serial_bags_and_reuse_the_cache(tmp_path):
    done = []
    parallel = simulate_all(SPECS, tmp_path / "parallel", workers=2, progress=lambda spec, bag: done.append(str(spec)))
    serial = simulate_all(SPECS, tmp_path / "serial", workers=0)
    assert sorted(done) == sorted(SPECS)
    for a, b in zip(parallel, serial):
        frames_a, frames_b = list(frames_of(a)), list(frames_of(b))
        assert len(frames_a) == len(frames_b) > 0
        for pa, pb in zip(frames_a, frames_b):
            assert pa.dtype == pb.dtype and len(pa) > 100 and np.array_equal(pa, pb)
    again = []
    assert simulate_all(SPECS, tmp_path / "parallel", workers=2, progress=lambda s, b: again.append(s)) == parallel
    assert again == []  # all cached: nothing simulated, no cluster started
