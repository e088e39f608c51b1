"""Golden clouds: every shipped scenario's first frames, recorded through ``run``, equal the committed ones.

A change that changes clouds rewrites ``test/golden/clouds.yaml`` in the same commit and says why
(``python -m lidar_weather_sim.testing.golden --write test/golden/clouds.yaml``).
"""

from pathlib import Path

import numpy as np
import pytest
import yaml

from lidar_weather_sim.testing.golden import case_clouds, differences, frame_record, host_cpu, record_case, shipped_cases

GOLDEN = yaml.safe_load((Path(__file__).parent / "golden" / "clouds.yaml").read_text())
SAME_CPU = GOLDEN["cpu"] == host_cpu()


def test_the_golden_file_holds_every_shipped_case():
    assert sorted(GOLDEN["cases"]) == sorted(case.key for case in shipped_cases())


@pytest.mark.parametrize("case", shipped_cases(), ids=lambda case: case.key.replace(" ", "_"))
def test_clouds_equal_the_golden_ones(case):
    expected = GOLDEN["cases"][case.key]
    actual = record_case(case, GOLDEN["frames"], GOLDEN["seed"])
    assert all(frame["points"] > 0 for frame in actual)
    found = differences(expected, actual, SAME_CPU)
    assert not found, f"{case.key} differs from test/golden/clouds.yaml (cpu {host_cpu()}, golden {GOLDEN['cpu']}): " + "; ".join(found)


def test_a_one_ulp_change_of_one_coordinate_is_caught():
    case = shipped_cases()[0]
    points = case_clouds(case, 1, GOLDEN["seed"])[0]
    nudged = points.copy()
    nudged["x"][len(points) // 2] = np.nextafter(nudged["x"][len(points) // 2], np.inf)
    golden = GOLDEN["cases"][case.key][:1]
    assert differences(golden, [frame_record(points)], same_cpu=SAME_CPU) == []
    assert differences(golden, [frame_record(nudged)], same_cpu=True)
