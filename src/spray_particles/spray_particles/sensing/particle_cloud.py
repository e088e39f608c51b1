"""The particle message of ``spray_node`` (``/spray/particles``, sensor_msgs/PointCloud2), ROS-free.

One point per particle, world frame (``map``), at the header stamp:

| field            | type    | unit | meaning                                                        |
|------------------|---------|------|----------------------------------------------------------------|
| x, y, z          | float32 | m    | centre                                                         |
| radius           | float32 | m    | horizontal semi-axis: render sphere (inertial) or packet ball  |
| population       | uint8   | -    | 0 inertial particle, 1 drop packet                             |
| vertical         | float32 | m    | vertical semi-axis (= radius for inertial particles)           |
| cross_section_m2 | float32 | m^2  | summed cross-section of a packet's airborne drops (0 inertial) |
| object_id        | uint32  | -    | actor id of the vehicle that threw it                          |

The ``spray`` region with ``source: topic`` rebuilds its scatterers from these fields
alone, so the sensor sees the node's particles as it would see its own.
"""

from __future__ import annotations

import numpy as np

TOPIC_PARTICLES = "/spray/particles"
PARTICLE_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("radius", "<f4"), ("population", "u1"),
                           ("vertical", "<f4"), ("cross_section_m2", "<f4"), ("object_id", "<u4")])  # fmt: skip
#: the fields the ``spray`` region needs from the topic
TOPIC_FIELDS = tuple(PARTICLE_DTYPE.names)


def particle_cloud(positions: np.ndarray, radius_m, population: np.ndarray, vertical_m=None, cross_section_m2=0.0,
                   object_id=0) -> np.ndarray:  # fmt: skip
    """Structured array (PARTICLE_DTYPE) of particle centres (n, 3) m, horizontal and vertical semi-axes
    (m, one value or (n,); vertical defaults to the horizontal), populations (n,), drop cross-sections
    (m^2) and emitting actor ids."""
    out = np.zeros(len(positions), PARTICLE_DTYPE)
    out["x"], out["y"], out["z"] = positions[:, 0], positions[:, 1], positions[:, 2]
    out["radius"] = radius_m
    out["vertical"] = radius_m if vertical_m is None else vertical_m
    out["population"] = population
    out["cross_section_m2"] = cross_section_m2
    out["object_id"] = object_id
    return out
