"""Where the workspace's ``config/`` and ``maps/`` directories are.

Order: ``LWS_CONFIG_DIR`` / ``LWS_MAPS_DIR``; the source tree this module runs
from (colcon ``--symlink-install`` and plain checkouts); the package's ament
share directory (``share/lidar_weather_sim/{config,maps}``, installed by setup.py).
"""

from __future__ import annotations

import os
from pathlib import Path


def _find(name: str, env: str) -> Path:
    if os.environ.get(env):
        return Path(os.environ[env])
    for parent in Path(__file__).resolve().parents:
        if (parent / name).is_dir() and (parent / "src" / "lidar_weather_sim").is_dir():
            return parent / name
    try:
        from ament_index_python.packages import get_package_share_directory

        shared = Path(get_package_share_directory("lidar_weather_sim")) / name
        if shared.is_dir():
            return shared
    except (ImportError, LookupError):
        pass
    raise FileNotFoundError(f"cannot find the '{name}' directory: set {env} or run from the workspace")


def config_dir() -> Path:
    return _find("config", "LWS_CONFIG_DIR")


def maps_dir() -> Path:
    return _find("maps", "LWS_MAPS_DIR")
