"""The package layout is the architecture: its layers are checked, not only written down.

``.importlinter`` names the layers of ``lidar_weather_sim`` (nothing imports a layer above its own),
keeps rclpy under the ``ros`` subpackages and keeps the simulator free of its plugin packages.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import lidar_weather_sim

ROOT = Path(__file__).resolve().parents[1]


def test_import_contracts_hold():
    lint = shutil.which("lint-imports")
    assert lint, "lint-imports (import-linter, requirements.txt) is not installed"
    result = subprocess.run([lint, "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    contracts = (ROOT / ".importlinter").read_text().count("[importlinter:contract:")
    assert f"Contracts: {contracts} kept, 0 broken." in result.stdout


def test_the_top_level_stays_small():
    package = Path(lidar_weather_sim.__file__).parent
    modules = sorted(p.name for p in package.glob("*.py"))
    subpackages = sorted(p.name for p in package.iterdir() if (p / "__init__.py").is_file())
    assert len(modules) <= 12, modules
    assert len(subpackages) >= 6, subpackages
    layered = {line.strip() for line in (ROOT / ".importlinter").read_text().splitlines()}
    for name in subpackages:  # every subpackage has a place in the layers contract
        assert any(name in line.split(" | ") for line in layered), f"{name} is not in a layer of .importlinter"
