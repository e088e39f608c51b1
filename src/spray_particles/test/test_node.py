"""spray_node: message builders, and the node publishing particles over DDS."""

import sys

import numpy as np

from spray_particles.node import PARTICLE_DTYPE, TOPIC_PARTICLES, marker_array, particle_cloud


def test_particle_cloud_and_markers():
    pos = np.array([[1.0, 2.0, 0.3], [4.0, 5.0, 0.6], [7.0, 8.0, 0.9]])
    cloud = particle_cloud(pos, 0.009, np.array([0, 1, 0], np.uint8))
    assert cloud.dtype == PARTICLE_DTYPE and np.allclose(cloud["radius"], 0.009)
    from builtin_interfaces.msg import Time

    markers = marker_array(cloud, Time(sec=1), "map").markers
    assert [len(m.points) for m in markers] == [2, 1]
    assert markers[0].scale.x == np.float32(0.018) or abs(markers[0].scale.x - 0.018) < 1e-6
    assert markers[0].header.frame_id == "map"


def test_node_publishes_particles(ros, processes):
    from sensor_msgs.msg import PointCloud2

    from lidar_weather_sim.ros.conversions import msg_to_cloud

    got = []
    ros.node.create_subscription(PointCloud2, TOPIC_PARTICLES, lambda m: got.append(m), 10)
    processes.start(sys.executable, "-m", "spray_particles.node", "--ros-args", "-p", "scenario:=highway_spray",
                    "-p", "rate_hz:=20.0")  # fmt: skip
    assert ros.spin_until(lambda: any(m.width > 0 for m in got), 60.0), "no particles published"
    msg = next(m for m in got if m.width > 0)
    assert [f.name for f in msg.fields] == ["x", "y", "z", "radius", "population"]
    assert msg.header.frame_id == "map"
    cloud = msg_to_cloud(msg).points
    assert np.all(cloud["z"] > -0.5) and set(np.unique(cloud["population"])) <= {0, 1}
