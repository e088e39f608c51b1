"""Scenario values outside their physical range are refused at load, in one line naming the key.

The reported silent acceptances pinned (mount y = inf, z = NaN, actor size inf, speeds of 1e308,
``at_s: .inf``, booleans for numbers, ``seed: -1`` in the file, ``texture_seed: -1``, a lane change
to a lane that does not exist, deep YAML, a cross-field error printing the whole block), the ego
leaving the map, and seeded fuzzing: any value put at any numeric key of a scenario is either
accepted within that key's documented range or refused naming the key (``FUZZ_CASES=N``).
"""

from __future__ import annotations

import copy
import math
import os
import subprocess
import sys

import pydantic
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from lidar_weather_sim.core.config import ConfigError, load_yaml, validate
from lidar_weather_sim.regions.base import REGISTRY, RegionContext
from lidar_weather_sim.scenario.schema import Scenario, load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.testing.fixtures import simple_profile

CASES = int(os.environ.get("FUZZ_CASES", "200"))
BASE = load_scenario("highway_spray").model_dump(mode="json")


def _refused(mutate, source="s.yaml") -> str:
    data = copy.deepcopy(BASE)
    mutate(data)
    with pytest.raises(ConfigError) as err:
        validate(data, Scenario, source)
    return str(err.value)


@pytest.mark.parametrize("path, value, reason", [
    ("sensor.mount.y_m", math.inf, "key 'sensor.mount.y_m': value inf: Input should be a finite number"),
    ("sensor.mount.z_m", math.nan, "key 'sensor.mount.z_m': value nan: Input should be a finite number"),
    ("sensor.mount.x_m", 500.0, "key 'sensor.mount.x_m': value 500.0: Input should be less than or equal to 20"),
    ("actors.0.size.length_m", math.inf, "key 'actors.0.size.length_m': value inf: Input should be a finite number"),
    ("ego.speed_m_s", 1e308, "key 'ego.speed_m_s': value 1e+308: Input should be less than or equal to 150"),
    ("actors.0.speed_m_s", True, "key 'actors.0.speed_m_s': value True: a boolean is not a number"),
    ("duration_s", False, "key 'duration_s': value False: a boolean is not a number"),
    ("seed", -1, "key 'seed': value -1: Input should be greater than or equal to 0"),
    ("weather.wind.speed_m_s", 1e9, "key 'weather.wind.speed_m_s': value 1000000000.0: Input should be less than or equal to 120"),
])  # fmt: skip
def test_a_value_outside_its_range_is_refused_naming_the_key(path, value, reason):
    def put(data):
        *parents, last = path.split(".")
        for p in parents:
            data = data[int(p)] if p.isdigit() else data[p]
        data[last] = value

    assert _refused(put).splitlines() == [f"s.yaml: {reason}"]


def test_inf_in_a_yaml_file_is_refused(tmp_path):
    data = copy.deepcopy(BASE)
    data["ego"]["lane_changes"] = [{"at_s": 1.0, "to_lane": -1}]
    text = yaml.safe_dump(data).replace("at_s: 1.0", "at_s: .inf")
    (tmp_path / "s.yaml").write_text(text)
    with pytest.raises(ConfigError, match=r"key 'ego.lane_changes.0.at_s': value inf: Input should be a finite number"):
        load_yaml(tmp_path / "s.yaml", Scenario)


def test_a_cross_field_error_names_the_block_not_its_contents():
    def both(data):
        data["actors"][0]["lane"] = -1

    assert _refused(both) == "s.yaml: key 'actors.0': actor 100: 'lead_gap_m' places the actor; remove ['lane']"


def test_deep_yaml_is_one_line(tmp_path):
    (tmp_path / "deep.yaml").write_text("name: x\nregion_params: {cover: " + "[" * 3000 + "]" * 3000 + "}\n")
    with pytest.raises(ConfigError, match=r"deep.yaml: .*nested too deeply"):
        load_yaml(tmp_path / "deep.yaml", Scenario)


def test_a_region_seed_below_zero_is_named():
    with pytest.raises(ConfigError, match=r"key 'texture_seed': value -1: Input should be greater than or equal to 0"):
        REGISTRY.create("cover", {"texture_seed": -1}, RegionContext(simple_profile()))


def test_a_lane_change_to_a_missing_lane_is_refused_before_anything_runs(tmp_path):
    """Was: the run failed at t = 1 s and left a 1 s bag."""
    data = copy.deepcopy(BASE)
    data["ego"]["lane_changes"] = [{"at_s": 1.0, "to_lane": -9}]
    with pytest.raises(ConfigError, match=r"^ego: key 'lane_changes.0.to_lane': value -9: road '1': no lane -9"):
        World.build(validate(data, Scenario))
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data))
    proc = subprocess.run([sys.executable, "-m", "lidar_weather_sim.cli", "run", str(tmp_path / "s.yaml"), "--frames", "5",
                           "--out", str(tmp_path / "bag")], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 2 and "lane_changes.0.to_lane" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "bag").exists()


def test_run_stops_with_a_warning_when_the_ego_reaches_the_end_of_its_road(tmp_path):
    """Was: empty clouds written without a word after the ego left the map."""
    from lidar_weather_sim.sim.offline import run_scenario

    data = copy.deepcopy(BASE)
    data["ego"].update(s_m=990.0, speed_m_s=25.0)
    data["actors"], data["regions"], data["region_params"] = [], [], {}
    report = run_scenario(validate(data, Scenario), tmp_path / "bag", frames=30)
    assert report.stopped is not None and "reached the end of road '1' at 0.40 s" in report.stopped
    assert report.frames == 10  # the frames of 0-0.4 s at 25 Hz


def _numeric_keys(model: type[pydantic.BaseModel], data: dict, prefix: tuple = ()) -> list[tuple[tuple, object]]:
    """(key path, FieldInfo) of every float/int field reachable in ``data`` (lists: their first item)."""
    from lidar_weather_sim.core.config import _is_number

    out = []
    for name, field in model.model_fields.items():
        value = data.get(name) if isinstance(data, dict) else None
        ann = field.annotation
        sub = [a for a in (getattr(ann, "__args__", None) or (ann,)) if isinstance(a, type) and issubclass(a, pydantic.BaseModel)]
        inner = getattr(ann, "__args__", ())
        if _is_number(ann):
            out.append((prefix + (name,), field))
        elif sub and isinstance(value, dict):
            out += _numeric_keys(sub[0], value, prefix + (name,))
        elif inner and isinstance(inner[0], type) and issubclass(inner[0], pydantic.BaseModel) and value:
            out += _numeric_keys(inner[0], value[0], prefix + (name, 0))
    return out


def _bounds(field) -> tuple[float, float, bool, bool]:
    lo, hi, lo_open, hi_open = -math.inf, math.inf, False, False
    for m in field.metadata:
        for attr, strict in (("ge", False), ("gt", True)):
            if getattr(m, attr, None) is not None:
                lo, lo_open = float(getattr(m, attr)), strict
        for attr, strict in (("le", False), ("lt", True)):
            if getattr(m, attr, None) is not None:
                hi, hi_open = float(getattr(m, attr)), strict
    return lo, hi, lo_open, hi_open


FUZZ_BASE = copy.deepcopy(BASE)
FUZZ_BASE["ego"]["lane_changes"] = [{"at_s": 1.0, "to_lane": -1}]
KEYS = _numeric_keys(Scenario, FUZZ_BASE)
_values = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(2**70), 2**70), st.booleans(),
                    st.sampled_from(["1.5", "inf", "", None, [], {}]))  # fmt: skip


@settings(max_examples=CASES, deadline=None)
@given(key=st.sampled_from(KEYS), value=_values)
def test_fuzz_a_value_at_any_numeric_key_is_in_range_or_refused_naming_the_key(key, value):
    path, field = key
    data = copy.deepcopy(FUZZ_BASE)
    node = data
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    try:
        scenario = validate(data, Scenario, "s.yaml")
    except ConfigError as err:
        assert f"key '{'.'.join(map(str, path))}'" in str(err) or "s.yaml: " in str(err), str(err)
        assert all(line.startswith("s.yaml: ") for line in str(err).splitlines())
        return
    got = scenario.model_dump()
    for p in path:
        got = got[p]
    if got is None:
        return
    assert not isinstance(value, bool) and math.isfinite(float(got)), (path, value)
    lo, hi, lo_open, hi_open = _bounds(field)
    assert (lo < got if lo_open else lo <= got) and (got < hi if hi_open else got <= hi), (path, value, got)
