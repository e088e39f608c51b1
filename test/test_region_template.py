"""templates/region_template: colcon skips it in place; a copy builds offline, registers its region by entry
point, and that region changes a simulated frame as its physics says (a uniform haze: exp(-2 alpha R))."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
TEMPLATE = REPO / "templates" / "region_template"
COLCON = shutil.which("colcon")

pytestmark = pytest.mark.skipif(COLCON is None, reason="colcon is not installed (make setup installs it)")


def _run(cmd, cwd, timeout=300, **kw):
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout, **kw)


def _offline() -> list[str]:
    """``unshare -n`` (no network at all) where this machine allows it, else nothing: the build must not need one."""
    probe = shutil.which("unshare") and _run(["unshare", "-n", "true"], REPO, timeout=30)
    return ["unshare", "-n"] if probe and probe.returncode == 0 else []


def _readme_block(heading: str) -> str:
    """The first ```bash block after ``heading`` in the template's README (the commands a user types)."""
    text = (TEMPLATE / "README.md").read_text()
    match = re.search(re.escape(heading) + r".*?```bash\n(.*?)```", text, re.S)
    assert match, f"no bash block after {heading!r} in {TEMPLATE / 'README.md'}"
    return match.group(1)


def _in_workspace(ws: Path, code: str) -> subprocess.CompletedProcess:
    """Python ``code`` in a shell that sourced the workspace's install/local_setup.bash (as the README says)."""
    script = f"source {shlex.quote(str(ws / 'install' / 'local_setup.bash'))} && exec {shlex.quote(sys.executable)} -c {shlex.quote(code)}"
    return _run(["bash", "-c", script], ws)


def test_colcon_skips_the_template_in_place_but_lists_a_copy(tmp_path):
    listed = _run([COLCON, "list", "--names-only", "--base-paths", str(TEMPLATE.parent)], REPO)
    assert listed.returncode == 0, listed.stderr
    assert listed.stdout.split() == []
    shutil.copytree(TEMPLATE, tmp_path / "region_template", ignore=shutil.ignore_patterns("COLCON_IGNORE", "__pycache__"))
    copy = _run([COLCON, "list", "--names-only", "--base-paths", str(tmp_path)], tmp_path)
    assert copy.stdout.split() == ["region_template"], copy.stderr


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Path:
    """A colcon workspace holding the template as it is (src/region_template) and a copy renamed by the README's
    own commands (src/my_region), built with ``colcon build --symlink-install`` without network."""
    ws = tmp_path_factory.mktemp("ws")
    (ws / "src").mkdir()
    shutil.copytree(TEMPLATE, ws / "src" / "region_template", ignore=shutil.ignore_patterns("COLCON_IGNORE", "__pycache__"))
    shutil.copytree(TEMPLATE, ws / "templates" / "region_template", ignore=shutil.ignore_patterns("__pycache__"))
    renamed = _run(["bash", "-euo", "pipefail", "-c", _readme_block("## Copy and rename")], ws)
    assert renamed.returncode == 0, renamed.stderr
    env = {**os.environ, "PIP_NO_INDEX": "1"}
    build = _run(_offline() + [COLCON, "--log-base", str(ws / "log"), "build", "--symlink-install",
                               "--base-paths", str(ws / "src"), "--build-base", str(ws / "build"),
                               "--install-base", str(ws / "install")], ws, env=env)  # fmt: skip
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    return ws


CHECK = textwrap.dedent("""
    import json
    import numpy as np
    from lidar_weather_sim.core.config import ConfigError
    from lidar_weather_sim.regions.base import REGISTRY, RegionContext
    from lidar_weather_sim.sim.simulator import LidarSimulator
    from lidar_weather_sim.testing.fixtures import one_frame, scene_of, simple_profile, wall

    profile = simple_profile()
    scene = scene_of(wall(20.0, "concrete", 1, half_width=1.5), wall(80.0, "concrete", 2))

    def frame(params):
        regions = [] if params is None else [("template_region", REGISTRY.create("template_region", params, RegionContext(profile)))]
        pts = one_frame(LidarSimulator(profile, scene, regions=regions, seed=0)).points
        centre = pts[(pts["object_id"] == 1) & (np.abs(pts["azimuth"]) < 1e-6)]
        return {"near": int(np.sum(pts["object_id"] == 1)), "far": int(np.sum(pts["object_id"] == 2)),
                "centre_epw": float(centre["epw"][0]), "centre_distance": float(centre["distance"][0])}

    try:
        REGISTRY.create("template_region", {"visual_range_m": -1.0}, RegionContext(profile))
        refused = ""
    except ConfigError as exc:
        refused = str(exc)
    print(json.dumps({
        "names": REGISTRY.names(),
        "alpha_500": REGISTRY.create("template_region", {"visual_range_m": 500.0}, RegionContext(profile)).alpha,
        "my_region_alpha": REGISTRY.create("my_region", {"extinction_per_m": 0.02}, RegionContext(profile)).alpha,
        "refused": refused,
        "clear": frame(None), "hazy": frame({"extinction_per_m": 0.01}), "default": frame({}),
    }))
""")


def _epw_amplitude(epw, fwhm=0.6, threshold=4.0):
    """Peak amplitude of a Gaussian pulse whose width above ``threshold`` is ``epw`` (simple_profile: pulse FWHM 0.6 m,
    threshold mu + 3 sigma = 4), as in src/lidar_weather_sim/test/test_regions.py."""
    sigma = fwhm / (2 * np.sqrt(2 * np.log(2)))
    return threshold * np.exp((epw / (2 * sigma)) ** 2 / 2)


@pytest.mark.slow
def test_installed_template_is_a_working_region(workspace):
    done = _in_workspace(workspace, CHECK)
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert {"template_region", "my_region", "cover", "atmosphere", "spray"} <= set(out["names"])
    assert out["alpha_500"] == pytest.approx(3.912 / 500.0)
    assert out["my_region_alpha"] == 0.02
    assert "region 'template_region' parameters: key 'visual_range_m'" in out["refused"]
    clear, hazy, default = out["clear"], out["hazy"], out["default"]
    # the wall at 80 m is seen in clear air and lost in the haze; the one at 20 m is kept, dimmer by exp(-2 alpha R)
    assert clear["far"] > 0 and hazy["far"] == 0 and default["far"] == 0
    assert hazy["near"] == clear["near"] > 0
    ratio = _epw_amplitude(hazy["centre_epw"]) / _epw_amplitude(clear["centre_epw"])
    assert ratio == pytest.approx(np.exp(-2 * 0.01 * clear["centre_distance"]), rel=1e-3)
    assert hazy["centre_distance"] == pytest.approx(clear["centre_distance"], abs=1e-4)


@pytest.mark.slow
def test_template_tests_pass_in_both_copies(workspace):
    """The tests shipped in the template run against the installed packages (as ``colcon test`` would)."""
    tests = [str(workspace / "src" / name / "test") for name in ("region_template", "my_region")]
    code = ("import sys, pytest; sys.exit(pytest.main(['-q', '-p', 'no:cacheprovider', '--import-mode=importlib', "
            f"*{tests!r}]))")  # fmt: skip
    done = _in_workspace(workspace, code)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert re.search(r"\b6 passed\b", done.stdout), done.stdout[-1000:]
