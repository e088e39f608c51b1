"""lidar_sim_node's start gate and synchronous mode over real DDS (the node in its own process, the test as
the graph's other nodes).

- ``wait_for_ready``: no clock and no cloud before every named node has said it is ready on /<node>/ready.
- ``synchronous``: cloud k+1 is not simulated before cloud k is answered on ``sync_topics`` (header stamp =
  the cloud's); a speed command for cloud k takes effect at the start of frame k+1 (stamp + 40 ms on scala4);
  a silent consumer ends the run with status 1 and one line naming its topic.
"""

from __future__ import annotations

import sys
import time

import numpy as np
import pytest

pytestmark = pytest.mark.integration

S = 1_000_000_000
PERIOD_NS = 40_000_000  # scala4: 25 Hz


def sim_node(processes, **params):
    args = [sys.executable, "-m", "lidar_weather_sim.ros.lidar_sim_node", "--ros-args",
            "-p", "scenario:=highway_clear", "-p", "realtime_factor:=0.0"]  # fmt: skip
    for name, value in params.items():
        args += ["-p", f"{name}:={str(value).lower() if isinstance(value, bool) else value}"]
    return processes.start(*args)


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * S + msg.header.stamp.nanosec


def answer(stamp, speed: float):
    from geometry_msgs.msg import TwistStamped

    cmd = TwistStamped()
    cmd.header.stamp = stamp
    cmd.twist.linear.x = speed
    return cmd


def test_the_clock_starts_only_once_every_named_node_is_ready(processes, ros):
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import Bool

    from lidar_weather_sim.ros.readiness import READY_QOS

    proc = sim_node(processes, wait_for_ready="[pytest_peer_a, pytest_peer_b]", max_frames=5)
    clouds = []
    ros.node.create_subscription(PointCloud2, "/lidar/points", clouds.append, qos_profile_sensor_data)
    ready_a = ros.node.create_publisher(Bool, "/pytest_peer_a/ready", READY_QOS)
    ready_b = ros.node.create_publisher(Bool, "/pytest_peer_b/ready", READY_QOS)
    ready_a.publish(Bool(data=True))
    assert ros.spin_until(lambda: "pytest_peer_a is ready" in processes.output(proc), timeout_s=60), processes.output(proc)
    ros.spin_until(lambda: False, timeout_s=2.0)
    assert not clouds and proc.poll() is None  # one of two ready: the clock stands
    ready_b.publish(Bool(data=True))
    assert ros.spin_until(lambda: len(clouds) >= 5, timeout_s=30), processes.output(proc)
    assert stamp_ns(clouds[0]) < PERIOD_NS  # the first frame: nothing was cast before the gate opened


def test_a_node_never_ready_ends_the_run_with_one_line(processes):
    proc = sim_node(processes, wait_for_ready="[pytest_never]", ready_timeout_s=3.0)
    assert proc.wait(timeout=60) == 1
    out = processes.output(proc)
    assert "not ready after 3 s: pytest_never (no true on /pytest_never/ready)" in out, out


def test_synchronous_mode_waits_for_each_answer_and_applies_it_at_the_next_frame(processes, ros):
    from geometry_msgs.msg import TwistStamped
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import PointCloud2
    from tf2_msgs.msg import TFMessage

    proc = sim_node(processes, synchronous=True, max_frames=12)
    clouds, tfs = [], []
    ros.node.create_subscription(PointCloud2, "/lidar/points", clouds.append, qos_profile_sensor_data)
    ros.node.create_subscription(TFMessage, "/tf", tfs.append, 100)
    cmd = ros.node.create_publisher(TwistStamped, "/ego/cmd_speed", 10)
    rng = np.random.default_rng(7)
    answered: list[int] = []
    while len(answered) < 12:
        assert ros.spin_until(lambda: len(clouds) > len(answered), timeout_s=60), processes.output(proc)
        # the clock waits: however long the answer takes, no further cloud is cast meanwhile
        ros.spin_until(lambda: False, timeout_s=float(rng.uniform(0.0, 0.4)))
        assert len(clouds) == len(answered) + 1, (len(clouds), len(answered))
        cloud = clouds[len(answered)]
        speed = 0.0 if len(answered) == 5 else 30.0  # frame 5 answered with a stop, the others with 30 m/s
        cmd.publish(answer(cloud.header.stamp, speed))
        answered.append(stamp_ns(cloud))
    assert proc.wait(timeout=30) == 0, processes.output(proc)
    assert np.diff(answered).tolist() == [PERIOD_NS] * 11  # every frame, none skipped
    # base_link's x on /tf against time: 30 m/s from frame 1's start, standing from frame 6's start, then 30 again
    ego = [(stamp_ns(ts), ts.transform.translation.x) for m in tfs for ts in m.transforms if ts.child_frame_id == "base_link"]
    t, x = np.array(ego, dtype=float).T
    v = np.diff(x) / (np.diff(t) / S)
    mid = 0.5 * (t[1:] + t[:-1])
    stopped = (mid > answered[5] + PERIOD_NS) & (mid < answered[6] + PERIOD_NS)
    assert np.allclose(v[stopped], 0.0, atol=1e-6), v[stopped]
    moving = (mid > answered[1] + PERIOD_NS) & (mid < answered[5] + PERIOD_NS)
    assert np.allclose(v[moving], 30.0, atol=1e-4), v[moving]


@pytest.mark.parametrize("publisher, reason", [(False, "no publisher on /ego/cmd_speed after 6 s"),
                                               (True, "/ego/cmd_speed did not answer the cloud stamped 0.010 s within 6 s")])  # fmt: skip
def test_a_silent_consumer_ends_the_run_with_one_line(processes, ros, publisher, reason):
    from geometry_msgs.msg import TwistStamped

    if publisher:
        ros.node.create_publisher(TwistStamped, "/ego/cmd_speed", 10)
    # 6 s: the node must discover the test's publisher within the timeout on a loaded machine (2 s was too short in CI)
    proc = sim_node(processes, synchronous=True, sync_timeout_s=6.0)
    start = time.monotonic()
    assert ros.spin_until(lambda: proc.poll() is not None, timeout_s=90), processes.output(proc)
    out = processes.output(proc)
    assert proc.returncode == 1 and reason in out, out
    assert "Traceback" not in out and time.monotonic() - start < 60
