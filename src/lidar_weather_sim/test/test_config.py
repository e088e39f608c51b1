"""Configuration errors name the file, the key and the value."""

import pydantic
import pytest

from lidar_weather_sim.core.config import ConfigError, ConfigModel, dump_yaml, load_yaml


class Beam(ConfigModel):
    elevation_deg: float = pydantic.Field(ge=-90, le=90, description="Beam elevation (deg)")


class Profile(ConfigModel):
    name: str
    rate_hz: float = pydantic.Field(gt=0, description="Frame rate (Hz)")
    beams: list[Beam]


def test_valid_file_loads(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("name: s\nrate_hz: 25\nbeams:\n  - elevation_deg: -1.2\n  - elevation_deg: 0.4\n")
    profile = load_yaml(path, Profile)
    assert profile.rate_hz == 25.0
    assert [b.elevation_deg for b in profile.beams] == [-1.2, 0.4]
    dumped = tmp_path / "dumped.yaml"
    dumped.write_text(dump_yaml(profile))
    assert load_yaml(dumped, Profile) == profile


@pytest.mark.parametrize(
    "text, expected",
    [
        ("name: s\nrate_hz: -3\nbeams: []\n", "key 'rate_hz': value -3"),
        ("name: s\nrate_hz: 10\nbeams:\n  - elevation_deg: 95\n", "key 'beams.0.elevation_deg': value 95"),
        ("name: s\nrate_hz: fast\nbeams: []\n", "key 'rate_hz': value 'fast'"),
        ("name: s\nrate_hz: 10\nbeams: []\nrange_m: 3\n", "unknown key 'range_m'"),
        ("name: s\nbeams: []\n", "missing key 'rate_hz'"),
        ("name: s\nrate_hz: [10\n", "invalid YAML"),
    ],
)
def test_errors_name_file_key_and_value(tmp_path, text, expected):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_yaml(path, Profile)
    assert str(path) in str(err.value)
    assert expected in str(err.value)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="nope.yaml: cannot read"):
        load_yaml(tmp_path / "nope.yaml", Profile)
