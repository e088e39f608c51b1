"""spray_node: message builders, and the node publishing particles over DDS."""

import sys

import numpy as np
import pytest

from spray_particles.sensing.particle_cloud import PARTICLE_DTYPE, TOPIC_FIELDS, TOPIC_PARTICLES, particle_cloud
from spray_particles.ros.node import marker_array


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
    processes.start(sys.executable, "-m", "spray_particles.ros.node", "--ros-args", "-p", "scenario:=highway_spray",
                    "-p", "rate_hz:=20.0")  # fmt: skip
    assert ros.spin_until(lambda: any(m.width > 0 for m in got), 60.0), "no particles published"
    msg = next(m for m in got if m.width > 0)
    assert tuple(f.name for f in msg.fields) == TOPIC_FIELDS
    assert msg.header.frame_id == "map"
    cloud = msg_to_cloud(msg).points
    assert np.all(cloud["z"] > -0.5) and set(np.unique(cloud["population"])) <= {0, 1}


def test_sim_node_sees_the_particles_spray_node_publishes(ros, processes, tmp_path):
    """spray_node (on lidar_sim_node's /clock) publishes particles; lidar_sim_node with the spray region's
    source 'topic' turns them into spray detections in front of the car that throws them."""
    import yaml
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import PointCloud2

    from lidar_weather_sim.core.paths import config_dir
    from lidar_weather_sim.core.points import Label
    from lidar_weather_sim.ros.conversions import msg_to_cloud, stamp_to_ns

    scenario = yaml.safe_load((config_dir() / "scenarios" / "highway_spray.yaml").read_text())
    scenario["regions"] = ["spray"]
    scenario["region_params"]["spray"]["source"] = "topic"
    path = tmp_path / "highway_spray_from_topic.yaml"
    path.write_text(yaml.safe_dump(scenario))
    spray = processes.start(sys.executable, "-m", "spray_particles.ros.node", "--ros-args", "-p", "scenario:=highway_spray",
                            "-p", "use_sim_time:=true", "-p", "rate_hz:=50.0")  # fmt: skip
    assert ros.spin_until(lambda: ros.node.count_publishers(TOPIC_PARTICLES) > 0, 60.0), processes.output(spray)
    clouds = []
    ros.node.create_subscription(PointCloud2, "/lidar/points", clouds.append, qos_profile_sensor_data)
    sim = processes.start(sys.executable, "-m", "lidar_weather_sim.ros.lidar_sim_node", "--ros-args", "-p",
                          f"scenario:={path}", "-p", "realtime_factor:=1.0", "-p", "max_frames:=100")  # fmt: skip
    # the last 0.8 s of 4 s: spray_node discovers the sim's /clock and the sim its particles within ~1.5 s even
    # on one busy core (then the particles need ~0.5 s to fill the wake)
    late = lambda: [m for m in clouds if stamp_to_ns(m.header.stamp) >= 3_200_000_000]  # noqa: E731
    assert ros.spin_until(lambda: len(late()) >= 10, 120.0), processes.output(sim) + processes.output(spray)
    points = np.concatenate([msg_to_cloud(m).points for m in late()])
    sprayed = points[points["label"] == Label.SPRAY]
    vehicle = points[(points["label"] == Label.VEHICLE) & (points["object_id"] == 100)]
    assert len(sprayed) >= 10 and set(np.unique(sprayed["object_id"])) == {100}
    assert np.median(sprayed["x"]) < np.median(vehicle["x"]) + 1.0 and np.median(sprayed["y"]) > 1.5


@pytest.mark.slow
def test_actors_from_tf_move_the_emitters(ros, processes):
    """actors_from_tf: vehicle 100 on /tf (map -> actor_100, 25 m/s along +x at y = 0; the scenario puts it
    in the left lane, y ~ 3.6 m) throws its spray there, stamped with the /tf time; nothing before its frame."""
    from geometry_msgs.msg import TransformStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    from tf2_msgs.msg import TFMessage

    from lidar_weather_sim.ros.conversions import msg_to_cloud, stamp_to_ns

    t0, tick = 1_700_000_000 * 10**9, 10_000_000
    got = []
    ros.node.create_subscription(PointCloud2, TOPIC_PARTICLES, got.append, 100)
    tf = ros.node.create_publisher(TFMessage, "/tf", QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    proc = processes.start(sys.executable, "-m", "spray_particles.ros.node", "--ros-args", "-p", "scenario:=highway_spray",
                           "-p", "actors_from_tf:=true", "-p", "rate_hz:=25.0")  # fmt: skip
    assert ros.spin_until(lambda: tf.get_subscription_count() > 0 and ros.node.count_publishers(TOPIC_PARTICLES) > 0,
                          60.0), processes.output(proc)  # fmt: skip
    for k in range(150):  # 1.5 s of /tf
        msg = TransformStamped()
        ns = t0 + k * tick
        msg.header.stamp.sec, msg.header.stamp.nanosec = ns // 10**9, ns % 10**9
        msg.header.frame_id, msg.child_frame_id = "map", "actor_100"
        msg.transform.translation.x, msg.transform.translation.z = 100.0 + 25.0 * k * tick * 1e-9, 0.0
        msg.transform.rotation.w = 1.0
        tf.publish(TFMessage(transforms=[msg]))
        ros.spin_until(lambda: False, 0.005)
    last = t0 + 149 * tick
    assert ros.spin_until(lambda: got and stamp_to_ns(got[-1].header.stamp) >= last - 40_000_000, 60.0), \
        processes.output(proc)  # fmt: skip
    stamps = [stamp_to_ns(m.header.stamp) for m in got]
    assert stamps[0] == t0 and all(b - a == 40_000_000 for a, b in zip(stamps, stamps[1:]))  # 25 Hz of /tf time
    cloud = msg_to_cloud(got[-1]).points
    car_x = 100.0 + 25.0 * (stamps[-1] - t0) * 1e-9
    assert len(cloud) > 100 and set(np.unique(cloud["object_id"])) == {100}
    assert abs(np.median(cloud["y"])) < 1.5 and np.median(cloud["x"]) < car_x  # behind the /tf car, in its lane
    assert proc.poll() is None
