"""The Fast DDS profile every node of this project starts with: dense clouds reach other processes.

With Fast DDS' defaults a process shares a 0.5 MiB shared-memory segment, which cannot hold one
OS1-128 x 2048 cloud (~6 MB); such a cloud goes over UDP in fragments that a loaded host drops, and no
cloud arrives (measured: 0 of ~100 six-MB clouds in 10 s, with the profile ~95). It is the sending
process whose segment counts, so every node that publishes clouds loads
``config/fastdds_large_messages.xml`` (a 32 MiB segment) unless the user named a profile file of their
own (``FASTDDS_DEFAULT_PROFILES_FILE`` or ``FASTRTPS_DEFAULT_PROFILES_FILE``), chose the transports
(``FASTDDS_BUILTIN_TRANSPORTS``), runs another RMW, or /dev/shm has no room for the segment.
Subscribers need nothing.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import MutableMapping
from pathlib import Path

from lidar_weather_sim.core.paths import config_dir

PROFILE_VARIABLES = ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
FAST_DDS_RMWS = ("", "rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp")
SEGMENT_BYTES = 32 * 2**20  # the profile's segment_size


def _shm_has_room(path: str = "/dev/shm") -> bool:
    try:
        return os.access(path, os.W_OK) and shutil.disk_usage(path).free >= 2 * SEGMENT_BYTES
    except OSError:
        return False


def large_message_profile() -> Path:
    return config_dir() / "fastdds_large_messages.xml"


def use_large_message_profile(environ: MutableMapping[str, str] = os.environ) -> Path | None:
    """Point Fast DDS at :func:`large_message_profile` in ``environ`` (call before ``rclpy.init``).

    Returns the file set, or None where the user's own profile or another RMW is left as it is."""
    chosen = any(environ.get(name) for name in (*PROFILE_VARIABLES, "FASTDDS_BUILTIN_TRANSPORTS"))
    if chosen or environ.get("RMW_IMPLEMENTATION", "") not in FAST_DDS_RMWS or not _shm_has_room():
        return None
    path = large_message_profile()
    if not path.is_file():
        return None
    environ[PROFILE_VARIABLES[0]] = str(path)  # the older name makes rmw print a deprecation warning
    return path
