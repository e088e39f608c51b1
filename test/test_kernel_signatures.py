"""Numba kernels take at most 12 parameters: more travel as named groups (NamedTuples of arrays and
scalars), so a call reads by name and not by position.

Walks every module of the three packages (the ``ros`` subpackages apart: they need ROS and hold no
kernels) and checks each numba dispatcher defined there.
"""

from __future__ import annotations

import importlib
import pkgutil

import pytest
from numba.core.dispatcher import Dispatcher

MAX_PARAMETERS = 12
PACKAGES = ("lidar_weather_sim", "spray_particles", "weather_filter")


def kernels(package_name: str):
    """(module name, kernel name, parameter count) of every numba kernel defined in the package."""
    package = importlib.import_module(package_name)
    for info in pkgutil.walk_packages(package.__path__, f"{package_name}."):
        if "ros" in info.name.split("."):
            continue
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            if isinstance(value, Dispatcher) and value.py_func.__module__ == module.__name__:
                yield info.name, name, value.py_func.__code__.co_argcount


@pytest.mark.parametrize("package_name", PACKAGES)
def test_kernels_take_at_most_12_parameters(package_name):
    found = list(kernels(package_name))
    assert found, f"no numba kernels found in {package_name}: the walk missed them"
    offenders = [f"{module}.{name}: {count} parameters" for module, name, count in found if count > MAX_PARAMETERS]
    assert not offenders, "group the inputs of these kernels (NamedTuples):\n" + "\n".join(offenders)
