"""Reality-gap workflow: make-measured hides effects, gap names them, fits them and shrinks the gap; compare.

The diagnosis tests run on 60 highway_clear scala4 frames with the command's default budgets
(lidar_weather_sim.gap: 30 calibration, 30 held-out, 6 screening frames); each checks that exactly the hidden effects are named,
that the main parameter comes back within 15 % and that the held-out gap at least halves.
"""

from __future__ import annotations

import json
import subprocess

import pytest
import yaml

from lidar_weather_sim.core.engine import Engine
from lidar_weather_sim.core.names import RETURN_MODES
from lidar_weather_sim.core.paths import config_dir
from lidar_weather_sim.gap.command import SearchLog, run_gap
from lidar_weather_sim.scenario.effects import EFFECTS, apply_effects, parse_effect, search_grid
from lidar_weather_sim.references.measured import RECOVERY_CASES, Nuisance, case_scenario, make_measured
from lidar_weather_sim.io.bags import bag_info
from lidar_weather_sim.scenario.schema import Scenario, load_scenario

FRAMES = 60


@pytest.fixture(scope="module")
def highway() -> Scenario:
    return load_scenario("highway_clear")


def _diagnose(scenario: Scenario, hidden: list[str], tmp_path) -> tuple[dict, list]:
    scenario = case_scenario(scenario, hidden)
    effects = [parse_effect(text) for text in hidden]
    make_measured(scenario, effects, tmp_path / "measured", frames=FRAMES)
    return run_gap(tmp_path / "measured", scenario, tmp_path / "gap"), effects


CASES = RECOVERY_CASES


def hidden_names(hidden: list[str]) -> set[str]:
    return {h.split(":")[0] for h in hidden}


def beside_the_nuisance(effects: list[dict], hidden: str) -> list[dict]:
    """gap.json's ``effects`` but a range noise at the level of make-measured's own (2 cm, in quadrature) where
    none was hidden: the sensor family explains that nuisance (spray in last-return mode: 0.026 m, held-out gap
    0.0136 -> 0.0005), so naming it is right, not a phantom."""
    level = Nuisance().extra_range_noise_m
    return [e for e in effects if not (e["name"] == "sensor.range_noise" != hidden
                                       and 0.5 * level <= e["params"]["sigma"] <= 1.5 * level)]  # fmt: skip


@pytest.mark.validation
@pytest.mark.parametrize("hidden", CASES, ids=["+".join(h.split(":")[0] for h in c) for c in CASES])
def test_gap_names_exactly_the_hidden_effects_and_recovers_them(highway, hidden, tmp_path):
    result, effects = _diagnose(highway, hidden, tmp_path)
    assert all(e["refused"] for e in result["effects"] if not e["named"]), result  # a fit not named says why
    found = {e["name"]: e["params"] for e in result["effects"] if e["named"]}
    # The nuisance's extra range noise has one explanation in the model: the lightest thesis dirt
    # sample (1u, T 0.995) raises the range sigma by 26.7 %. Next to fog at 80 m and sun on the
    # thesis geometry it wins (held-out gap 0.0075 -> 0.0013). So where dirt is not hidden, a
    # dirt at T >= 0.99 is taken as the nuisance's absorber, not as a wrong name.
    absorber = found.get("cover.dirt", {}).get("transmission", 0.0) >= 0.99 and "cover.dirt" not in hidden_names(hidden)
    named = sorted(n for n in found if not (absorber and n == "cover.dirt"))
    assert named == sorted(e.name for e in effects), result
    for e in effects:
        got = found[e.name][e.spec.main]
        assert abs(got - e.value) <= 0.15 * e.value, (e.label(), got)
        if "actor" in e.params:
            assert found[e.name]["actor"] == e.params["actor"]
    assert result["gap_after"] <= 0.5 * result["gap_before"], result
    # the patched scenario is a runnable scenario holding the effects found
    patched = Scenario.model_validate(yaml.safe_load((tmp_path / "gap" / "patched_scenario.yaml").read_text()))
    assert set(patched.regions) >= {n.split(".")[0] for n in found if n != "sensor.sun"}
    for name in ("report.md", "gap_terms.png", "ranges_before_after.png", "bev_before_after.png"):
        assert (tmp_path / "gap" / name).stat().st_size > 0


@pytest.mark.validation
def test_gap_frees_an_accepted_effect_that_absorbed_the_missing_one(highway, tmp_path):
    """Sun 400 W/m^2 behind a dirt of 0.62: both dim the returns, and alone the dirt fits at 0.36; next to that
    dirt no sun helps (fitted at its 10 W/m^2 floor). The round with the accepted dirt free finds the pair."""
    hidden = [parse_effect("sensor.sun:irradiance=400"), parse_effect("cover.dirt:transmission=0.62")]
    make_measured(highway, hidden, tmp_path / "measured", frames=12)
    result = run_gap(tmp_path / "measured", highway, tmp_path / "gap", fit_frames=6, heldout_frames=6, screen_frames=2)
    found = {e["name"]: e["params"][EFFECTS[e["name"]].main] for e in result["effects"]}
    assert sorted(found) == ["cover.dirt", "sensor.sun"], result
    for e in hidden:
        assert abs(found[e.name] / e.value - 1.0) <= 0.15, (e.label(), found[e.name])
    assert result["gap_after"] <= 0.1 * result["gap_before"], result


@pytest.mark.validation
def test_clear_measurement_accepts_no_effect(highway, tmp_path):
    result, _ = _diagnose(highway, [], tmp_path)
    assert result["effects"] == []
    assert len(result["rejected"]) >= 8  # every candidate reported, with its held-out gap
    assert result["gap_before"] < 0.02  # what is left is the nuisance the model does not explain
    steps = (tmp_path / "gap" / SearchLog.FILE).read_text().splitlines()  # the search's steps, with the frames cast
    assert "gap before" in steps[0] and sum("held-out gap" in line for line in steps) >= 8, steps


def test_the_search_log_keeps_every_step_also_when_the_search_fails(tmp_path):
    """run_gap's SearchLog: each message with the seconds and frames cast so far, in order, passed on to the
    caller's progress; written to search.log beside gap.json also when the search raises (the steps up to it)."""
    seen = []
    with pytest.raises(RuntimeError):
        with SearchLog(tmp_path / "gap", lambda text, casts: seen.append((text, casts))) as log:
            log("gap before: 0.4134", 60)
            log("atmosphere.rain:intensity=10: held-out gap 0.1407", 400)
            raise RuntimeError("a worker died")
    lines = (tmp_path / "gap" / "search.log").read_text().splitlines()
    assert seen == [("gap before: 0.4134", 60), ("atmosphere.rain:intensity=10: held-out gap 0.1407", 400)]
    assert [line.split("frames cast")[0].split()[-1] for line in lines] == ["60", "400"]
    assert [line.split("frames cast  ")[1] for line in lines] == [text for text, _ in seen]
    assert float(lines[0].split()[0]) <= float(lines[1].split()[0])


def test_gap_prints_one_line_per_step_where_stderr_is_not_a_terminal(monkeypatch, capsys, tmp_path):
    """In a log (CI, nohup, a pipe) a progress bar is one line rewritten thousands of times: the command prints each
    step of the search on its own line instead, with the frames cast."""
    import lidar_weather_sim.gap.command as command
    from lidar_weather_sim.cli import main as cli_main

    def fake_run_gap(measured, scenario, out, progress=None, **kwargs):
        progress("gap before: 0.3363", 30)
        progress("atmosphere.snow:intensity=0.267109: held-out gap 0.1538", 812)
        return {"gap_before": 0.3363, "gap_after": 0.1538, "effects": [], "found": "no effect", "split": {}}

    monkeypatch.setattr(command, "run_gap", fake_run_gap)
    assert cli_main(["gap", str(tmp_path / "bag"), "--scenario", "highway_clear", "--out", str(tmp_path / "g")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err == ["gap: 30 frames cast: gap before: 0.3363",
                   "gap: 812 frames cast: atmosphere.snow:intensity=0.267109: held-out gap 0.1538"], err


def test_gap_evaluates_in_forked_copies_by_default_and_in_this_process_with_workers_0(monkeypatch, tmp_path):
    import lidar_weather_sim.gap.command as command
    from lidar_weather_sim.cli import main as cli_main

    asked = []

    def fake_run_gap(measured, scenario, out, **kwargs):
        asked.append((kwargs["workers"], kwargs["scheduler"]))
        return {"gap_before": 0.3, "gap_after": 0.1, "effects": [], "found": "no effect", "split": {}}

    monkeypatch.setattr(command, "run_gap", fake_run_gap)
    for extra in ([], ["--workers", "0"], ["--workers", "3"], ["--scheduler", "tcp://h:8786"]):
        assert cli_main(["gap", str(tmp_path / "bag"), "--scenario", "highway_clear", "--out", str(tmp_path / "g"),
                         *extra]) == 0  # fmt: skip
    assert asked == [(None, None), (0, None), (3, None), (None, "tcp://h:8786")]


def test_measured_bag_looks_like_a_real_recording(highway, tmp_path, cli):
    out = tmp_path / "m"
    done = subprocess.run([*cli, "make-measured", "highway_clear", "--hide", "atmosphere.rain:intensity=5",
                           "--frames", "20", "--out", str(out)], capture_output=True, text=True)  # fmt: skip
    assert done.returncode == 0, done.stderr
    info = bag_info(out)
    assert sorted(t.name for t in info.topics) == ["/clock", "/lidar/points", "/tf", "/tf_static"]
    fields = {f[0] for f in next(t for t in info.topics if t.name == "/lidar/points").pointcloud_fields}
    assert "label" not in fields and "object_id" not in fields
    assert {"x", "y", "z", "intensity", "channel", "distance", "echo", "epw"} <= fields
    clouds = next(t for t in info.topics if t.name == "/lidar/points").count
    assert 15 <= clouds <= 20  # a few frames may be dropped (nuisance)
    dropped = f", {20 - clouds} dropped by the nuisance model" if clouds < 20 else ""
    assert f"wrote {clouds} of 20 frames (" in done.stdout and f"points{dropped}) to" in done.stdout, done.stdout


def test_each_hidden_effect_changes_only_itself(highway):
    rain = apply_effects(highway, [parse_effect("atmosphere.rain:intensity=10")])
    assert rain.region_params["atmosphere"]["road_water_film_mm"] == 0.0  # rain does not wet the road
    assert "spray" not in rain.regions  # nor feed spray
    both = apply_effects(highway, [parse_effect("atmosphere.rain:intensity=10"),
                                   parse_effect("atmosphere.road_wet:water_film=0.7")])  # fmt: skip
    assert both.region_params["atmosphere"]["road_water_film_mm"] == 0.7
    snow = parse_effect("atmosphere.snow:intensity=1")
    assert not apply_effects(highway, [snow]).weather.road.snow_depth_m  # snowfall does not cover the road (None: none)
    covered = highway.model_copy(update={"weather": highway.weather.model_copy(update={
        "road": highway.weather.road.model_copy(update={"snow_depth_m": 0.05})})})  # fmt: skip
    assert apply_effects(covered, [snow]).weather.road.snow_depth_m == 0.05  # a scenario's snow cover stays
    with pytest.raises(ValueError, match="rain or snow"):
        apply_effects(highway, [parse_effect("atmosphere.rain:intensity=1"), parse_effect("atmosphere.snow:intensity=1")])
    sample = parse_effect("cover.dirt:sample=3l")
    assert sample.value == pytest.approx(0.654)
    mode = parse_effect("sensor.return_mode:mode=last")
    assert apply_effects(highway, [mode]).sensor.return_mode == "last"
    assert mode.label() == "sensor.return_mode:mode=last" and mode.with_value(mode.value) == mode
    assert [mode.with_value(x).params["mode"] for x in search_grid(mode.spec, 3)] == list(RETURN_MODES)


@pytest.mark.parametrize(
    "hide, reason",
    [("atmosphere.hail:intensity=3", "unknown effect 'atmosphere.hail'"),
     ("atmosphere.fog:visibility=30", "has no parameter 'visibility'"),
     ("sensor.sun:irradiance=bright", "needs a number"),
     ("spray:actor=100", "needs its main parameter 'water_film'"),
     ("atmosphere.rain:intensity=inf", "'intensity' must be a finite number above 0 (mm/h), got inf"),
     ("atmosphere.rain:intensity=1e9", "key 'intensity_mm_h': value 1000000000.0: Input should be less than or equal to 300"),
     ("sensor.sun:irradiance=-400", "must be a finite number above 0 (W/m^2), got -400"),
     ("cover.water:transmission=1.5", "at most 1, got 1.5"),
     ("atmosphere.fog:visual_range=80,visual_range=90", "parameter 'visual_range' given twice"),
     ("sensor.return_mode:mode=loudest", "'mode' must be one of strongest, last, dual, first, all, got 'loudest'")],
)  # fmt: skip
def test_bad_hide_specs_exit_2_with_one_line(cli, tmp_path, hide, reason):
    done = subprocess.run([*cli, "make-measured", "highway_clear", "--hide", hide, "--out", str(tmp_path / "x")],
                          capture_output=True, text=True)  # fmt: skip
    assert done.returncode == 2
    assert reason in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("command", ["make-measured", "gap"])
def test_the_removed_atmosphere_model_flag_exits_2_with_one_line(cli, tmp_path, command):
    done = subprocess.run([*cli, command, *(["x.bag"] if command == "gap" else []), "highway_clear",
                           "--atmosphere-model", "fitted", "--out", str(tmp_path / "x")],
                          capture_output=True, text=True)  # fmt: skip
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "--atmosphere-model was removed with the fitted atmosphere model" in done.stderr
    assert not (tmp_path / "x").exists()


def test_compare_writes_metrics_report_and_plots(highway, tmp_path, cli):
    make_measured(highway, [parse_effect("atmosphere.rain:intensity=10")], tmp_path / "measured", frames=20)
    make_measured(highway, [], tmp_path / "clear", frames=20)
    done = subprocess.run([*cli, "compare", str(tmp_path / "measured"), str(tmp_path / "clear"), "--out",
                           str(tmp_path / "cmp")], capture_output=True, text=True)  # fmt: skip
    assert done.returncode == 0, done.stderr
    m = json.loads((tmp_path / "cmp" / "metrics.json").read_text())
    assert m["frames"]["paired_by"] == "time" and m["frames"]["paired"] >= 15
    near = m["zones"]["near"]["detections_per_frame"]
    assert near["measured"][0] > 3.0 > 6 * near["simulated"][0]  # rain fills the near field
    assert m["zones"]["near"]["range_bray_curtis"] > 0.9
    assert m["gap"] > 0.2  # 0.26 (20 frames, 10 mm/h)
    assert 0.0 <= m["bev"]["jaccard_distance"] <= 1.0 and -1.0 <= m["bev"]["pearson"] <= 1.0
    assert set(m["near_field_parameters"]) >= {"n_total", "x_sigma", "epw_mean"}
    for name in ("report.md", "ranges.png", "bev.png", "returns_by_channel.png"):
        assert (tmp_path / "cmp" / name).stat().st_size > 0
    # a recording compared with itself has no gap
    same = subprocess.run([*cli, "compare", str(tmp_path / "clear"), str(tmp_path / "clear"), "--out",
                           str(tmp_path / "same")], capture_output=True, text=True)  # fmt: skip
    assert same.returncode == 0, same.stderr
    assert json.loads((tmp_path / "same" / "metrics.json").read_text())["gap"] == 0.0


@pytest.mark.validation
def test_gap_search_in_forked_copies_and_on_dask_workers_is_the_serial_diagnosis(highway, tmp_path):
    hidden = ["atmosphere.fog:visual_range=80"]
    scenario = case_scenario(highway, hidden)
    make_measured(scenario, [parse_effect(h) for h in hidden], tmp_path / "measured", frames=12)
    budgets = {"fit_frames": 4, "heldout_frames": 4, "screen_frames": 1}
    serial = run_gap(tmp_path / "measured", scenario, tmp_path / "serial", **budgets)
    assert [e["name"] for e in serial["effects"]] == ["atmosphere.fog"]
    forked = run_gap(tmp_path / "measured", scenario, tmp_path / "forked", workers=2, **budgets)
    assert json.dumps(forked, sort_keys=True) == json.dumps(serial, sort_keys=True)
    with Engine(workers=2) as cluster:
        dask = run_gap(tmp_path / "measured", scenario, tmp_path / "dask", scheduler=cluster.client.scheduler.address,
                       **budgets)  # fmt: skip
    assert json.dumps(dask, sort_keys=True) == json.dumps(serial, sort_keys=True)


@pytest.mark.parametrize("hidden", ["sensor.intensity_gamma:gamma=0.55", "sensor.range_bias:bias=-0.05",
                                    "sensor.range_noise:sigma=0.08", "sensor.ray_drop:probability=0.4"])
@pytest.mark.validation
def test_gap_names_a_hidden_sensor_response_among_the_sensor_effects(highway, hidden, tmp_path):
    effect = parse_effect(hidden)
    make_measured(highway, [effect], tmp_path / "measured", frames=24)
    result = run_gap(tmp_path / "measured", highway, tmp_path / "gap", families=("sensor",), fit_frames=8,
                     heldout_frames=8, screen_frames=2)  # fmt: skip
    found = {e["name"]: e["params"] for e in beside_the_nuisance(result["effects"], effect.name)}
    assert list(found) == [effect.name], result
    expected = effect.value
    if effect.name == "sensor.range_noise":  # make-measured's own 2 cm range noise adds in quadrature
        expected = (effect.value**2 + Nuisance().extra_range_noise_m**2) ** 0.5
    assert found[effect.name][effect.spec.main] == pytest.approx(expected, rel=0.15)
    assert result["gap_after"] <= 0.5 * result["gap_before"]
    patched = Scenario.model_validate(yaml.safe_load((tmp_path / "gap" / "patched_scenario.yaml").read_text()))
    assert patched.sensor.response != highway.sensor.response


@pytest.mark.validation
def test_gap_chooses_the_hidden_return_mode_in_spray(tmp_path):
    """Spray gives beams several echoes: a driver set to ``last`` (the profile: ``all``) is named - read off the
    points' return_type codes (gap.read_off) - and the re-simulation with it closes the gap."""
    spray = load_scenario("highway_spray")
    make_measured(spray, [parse_effect("sensor.return_mode:mode=last")], tmp_path / "measured", frames=24)
    result = run_gap(tmp_path / "measured", spray, tmp_path / "gap", families=("sensor",), fit_frames=8,
                     heldout_frames=8, screen_frames=2)  # fmt: skip
    found = beside_the_nuisance(result["effects"], "sensor.return_mode")
    assert [(e["name"], e["params"]) for e in found] == [("sensor.return_mode", {"mode": "last"})], result
    assert result["gap_after"] <= 0.1 * result["gap_before"]
    patched = Scenario.model_validate(yaml.safe_load((tmp_path / "gap" / "patched_scenario.yaml").read_text()))
    assert patched.sensor.return_mode == "last"
    assert "| sensor.return_mode | mode=last |" in (tmp_path / "gap" / "report.md").read_text()


@pytest.mark.validation
def test_gap_reads_dead_channels_off_the_recording(highway, tmp_path):
    """Two VLP-16 channels that return on the road and report nothing are named as the one set the recording shows; a clear
    recording of the same sensor names none (the same search, nothing hidden)."""
    vlp16 = highway.model_copy(update={"sensor": highway.sensor.model_copy(update={"profile": "vlp16"})})
    budgets = {"families": ("sensor",), "fit_frames": 8, "heldout_frames": 8, "screen_frames": 2}
    make_measured(vlp16, [parse_effect("sensor.dead_channels:channels=2+8")], tmp_path / "dead", frames=16)
    dead = run_gap(tmp_path / "dead", vlp16, tmp_path / "gap_dead", **budgets)
    # named first, exactly; on VLP-16 the search goes on to name make-measured's 2 cm range noise (hidden, right)
    first = dead["effects"][0]
    assert (first["name"], first["params"]) == ("sensor.dead_channels", {"channels": "2+8"}), dead
    assert [e["name"] for e in dead["effects"]] == ["sensor.dead_channels", "sensor.range_noise"], dead
    assert dead["gap_after"] <= 0.2 * dead["gap_before"]
    make_measured(vlp16, [], tmp_path / "clear", frames=16)
    clear = run_gap(tmp_path / "clear", vlp16, tmp_path / "gap_clear", **budgets)
    read_off = {"sensor.dead_channels", "sensor.weak_channels", "sensor.elevation_offsets"}
    assert not read_off & {e["name"] for e in clear["effects"] + clear["rejected"]}, clear
    assert "sensor.near_field_ghost" not in {e["name"] for e in clear["effects"]}, clear


@pytest.mark.validation
def test_gap_fits_the_near_field_ghosts_of_a_unit(highway, tmp_path):
    """A VLP-16 whose clean window gives 0.1 ghosts per beam and frame (about 4 % of them beyond its 0.3 m
    minimum range): ``sensor.near_field_ghost`` is named and its rate comes back within 15 % (measured: 0.1026),
    beside make-measured's own 2 cm range noise, and the gap closes."""
    vlp16 = highway.model_copy(update={"sensor": highway.sensor.model_copy(update={"profile": "vlp16"})})
    make_measured(vlp16, [parse_effect("sensor.near_field_ghost:rate=0.1")], tmp_path / "measured", frames=16)
    result = run_gap(tmp_path / "measured", vlp16, tmp_path / "gap", families=("sensor",), fit_frames=8,
                     heldout_frames=8, screen_frames=2)  # fmt: skip
    named = {e["name"]: e["params"] for e in result["effects"]}
    assert set(named) == {"sensor.near_field_ghost", "sensor.range_noise"}, result
    assert named["sensor.near_field_ghost"]["rate"] == pytest.approx(0.1, rel=0.15)
    assert result["gap_after"] <= 0.1 * result["gap_before"]
    patched = Scenario.model_validate(yaml.safe_load((tmp_path / "gap" / "patched_scenario.yaml").read_text()))
    assert patched.region_params["cover"]["near_field_ghost_per_beam"] == named["sensor.near_field_ghost"]["rate"]


@pytest.mark.validation
def test_gap_reads_weak_channels_and_elevation_offsets_off_the_recording(highway, tmp_path):
    """A VLP-16 whose channel 5 has a third of its gain and whose channels 3 and 9 point 0.4 deg up and 0.3 deg
    down: both are read off the recording and named first (gain within 5 %: intensity bytes are ~3.6 % apart;
    offsets exact), then make-measured's own 2 cm range noise, and the gap closes."""
    vlp16 = highway.model_copy(update={"sensor": highway.sensor.model_copy(update={"profile": "vlp16"})})
    hidden = [parse_effect("sensor.weak_channels:gains=5:0.33"), parse_effect("sensor.elevation_offsets:offsets=3:0.4+9:-0.3")]
    make_measured(vlp16, hidden, tmp_path / "measured", frames=16)
    result = run_gap(tmp_path / "measured", vlp16, tmp_path / "gap", families=("sensor",), fit_frames=8,
                     heldout_frames=8, screen_frames=2)  # fmt: skip
    named = {e["name"]: e["params"] for e in result["effects"]}
    assert set(named) == {"sensor.weak_channels", "sensor.elevation_offsets", "sensor.range_noise"}, result
    assert named["sensor.elevation_offsets"] == {"offsets": "3:0.4+9:-0.3"}
    channel, gain = named["sensor.weak_channels"]["gains"].split(":")
    assert channel == "5" and abs(float(gain) / 0.33 - 1.0) < 0.05, named
    assert abs(named["sensor.range_noise"]["sigma"] - 0.02) < 0.003  # make-measured's nuisance
    assert result["gap_after"] <= 0.05 * result["gap_before"]


@pytest.mark.validation
def test_a_right_name_is_still_given_and_nothing_is_left_unexplained(highway, tmp_path):
    """The model's own fog of 80 m (8 frames, budgets 4 / 4 / 2: ~60 s): the search names it at the model's own
    backscatter gain (1: the soft echoes are there) and the judgement after it reports no unexplained zone
    (lidar_weather_sim.gap.unexplained). Hidden rain of 10 mm/h was this test's case until the fog's gains
    and the range-law term: on 4 calibration frames its Brent fit stops at 12.1 mm/h and a snow of 0.38 mm/h wins the
    held-out frames by 0.002 (on all 8 frames the rain at 10 scores 0.0000, the snow 0.0029): noise at this budget;
    test_gap_names_exactly_the_hidden_effects_and_recovers_them[atmosphere.rain] names the rain on more frames."""
    make_measured(highway, [parse_effect("atmosphere.fog:visual_range=80")], tmp_path / "measured", frames=8)
    result = run_gap(tmp_path / "measured", highway, tmp_path / "gap", fit_frames=4, heldout_frames=4, screen_frames=2)
    assert [(e["name"], e["named"]) for e in result["effects"]] == [("atmosphere.fog", True)]
    params = result["effects"][0]["params"]
    assert params["visual_range"] == pytest.approx(80.0, rel=0.1) and "gain" not in params, params
    assert result["unexplained"] == [] and result["found"].startswith("atmosphere.fog (visual_range=")
    assert "| none | - | - | - | - |" in (tmp_path / "gap" / "report.md").read_text()


@pytest.mark.validation
def test_a_beer_lambert_fog_without_soft_echoes_is_named_at_its_visual_range(highway, tmp_path):
    """Case 0 of config/generator_draw.yaml: the Beer-Lambert fog of the fixed generator fog_loss (229 m, no soft
    echoes), 8 frames, budgets 4 / 4 / 2 (~70 s). Before the fog had a backscatter gain and the gap a range-law term
    the search fitted a sun to it (then refused by the judgement, nothing named). Now the fog is fitted at a low
    backscatter gain (the unit makes no soft echoes of it) and named within 10 % of its visual range; what is left
    unexplained is how the generator's pulses answer the loss (their widths), no zone's returns."""
    case = yaml.safe_load((config_dir() / "generator_draw.yaml").read_text())["cases"][0]
    assert (case["generator"], case["hide"]) == ("fog_loss", ["atmosphere.fog:visual_range=229.4"])
    make_measured(highway, [parse_effect(h) for h in case["hide"]], tmp_path / "measured", frames=8, seed=case["seed"],
                  profile=case["profile"], generator=case["generator"])  # fmt: skip
    result = run_gap(tmp_path / "measured", highway, tmp_path / "gap", profile=case["profile"], fit_frames=4,
                     heldout_frames=4, screen_frames=2)  # fmt: skip
    assert [(e["name"], e["named"]) for e in result["effects"]] == [("atmosphere.fog", True)]
    fog = result["effects"][0]["params"]
    assert fog["visual_range"] == pytest.approx(229.4, rel=0.1) and fog["gain"] <= 0.15, fog
    assert result["gap_after"] < 0.2 * result["gap_before"]
    assert all(u["aspect"] != "range" for u in result["unexplained"]), result["unexplained"]  # every zone's counts


@pytest.mark.validation
def test_a_dirt_that_only_absorbs_is_named_as_dirt_not_as_fog(highway, tmp_path):
    """A uniform dirt of one-way transmission 0.606 made by the fixed generators' cover (every return's power times
    T^2, no forward scattering, no cover returns), 8 frames of scala4, budgets 4 / 4 / 2 (~60 s). The model's
    generic dirt of that transmission takes the thesis' forward share (0.35: its heavy samples 3 and 5), whose wider
    beam keeps far returns the recording lost, and a fog of 150 m explained the recording better (held-out 0.057
    against 0.068). With the dirt's forward share searched (0 or the texture's) it is named: at a share of 0 and
    its transmission within 10 %, the held-out gap at least halved."""
    make_measured(highway, [parse_effect("cover.dirt:transmission=0.606")], tmp_path / "measured", frames=8,
                  seed=4242, profile="scala4", generator="fog_loss")  # fmt: skip
    result = run_gap(tmp_path / "measured", highway, tmp_path / "gap", profile="scala4", fit_frames=4,
                     heldout_frames=4, screen_frames=2)  # fmt: skip
    assert [(e["name"], e["named"]) for e in result["effects"]] == [("cover.dirt", True)], result["effects"]
    dirt = result["effects"][0]["params"]
    assert dirt["transmission"] == pytest.approx(0.606, rel=0.1) and dirt["forward"] == 0.0, dirt
    assert result["gap_after"] < 0.5 * result["gap_before"]
