"""Where the workspace's ``config/`` and ``maps/`` directories are.

Order: ``LWS_CONFIG_DIR`` / ``LWS_MAPS_DIR``; the source tree this module runs
from (colcon ``--symlink-install`` and plain checkouts); the package's ament
share directory (``share/lidar_weather_sim/{config,maps}``, installed by setup.py).

Data that ``make setup`` downloads or imports lives in the workspace's
``.venv/cache`` (``LWS_CACHE_DIR`` overrides it); configuration files name it
as ``cache:<path>`` (:func:`resolve_data_path`).
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


CACHE_PREFIX = "cache:"


def cache_dir() -> Path:
    """``LWS_CACHE_DIR``, else ``.venv/cache`` of the workspace this module runs from (it may not exist)."""
    if os.environ.get("LWS_CACHE_DIR"):
        return Path(os.environ["LWS_CACHE_DIR"])
    for parent in Path(__file__).resolve().parents:
        if (parent / ".venv").is_dir() and (parent / "src" / "lidar_weather_sim").is_dir():
            return parent / ".venv" / "cache"
    return config_dir().parent / ".venv" / "cache"


def resolve_data_path(name: str | Path, directory: Path | None = None) -> Path:
    """A file named in a configuration: ``cache:<path>`` relative to :func:`cache_dir` (which must
    exist: ``make setup`` creates it), else an absolute or existing path, else ``directory / name``."""
    text = str(name)
    if text.startswith(CACHE_PREFIX):
        path = cache_dir() / text[len(CACHE_PREFIX) :]
        if not path.is_file():
            raise FileNotFoundError(f"{text}: {path} does not exist (run make setup to import it)")
        return path
    path = Path(name)
    return path if directory is None or path.is_absolute() or path.exists() else directory / name
