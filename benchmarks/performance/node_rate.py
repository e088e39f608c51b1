"""Live node speed: ``lidar_sim_node`` in scenario mode at real time, over DDS, with every region on.

The node runs in its own process (its own ``ROS_DOMAIN_ID``, localhost discovery) with the
scenario ``--scenario`` (default highway_spray: the car ahead throws spray), ``--profile``
(default os1_128_2048, 10 Hz), ``realtime_factor`` 1 and ``time_step_s`` 0.01, regions
cover (dirt ``--dirt``) + atmosphere (rain ``--rain`` mm/h) + spray (``--packets`` drop packets
per wheel per tick). This process subscribes to ``/lidar/points`` (SensorDataQoS) and ``/clock``
for ``--seconds`` of wall time after the first cloud, then prints:

- simulated seconds advanced and the achieved real-time factor (simulated / wall);
- clouds delivered per simulated second (the profile's frame rate when none is lost) and per
  wall second;
- the lag behind real time at the end: wall time elapsed minus simulated time elapsed (s).

Both processes use ``--dds-profile`` (default ``config/fastdds_large_messages.xml``: a 32 MiB
shared-memory segment); with ``--dds-profile ''`` (Fast DDS defaults) an OS1-128 x 2048 cloud (~6 MB)
does not reach the other process on this machine. No assertion: the CI test of the same path counts
clouds in simulated time (``test/test_graphs.py``, regions on).

    python benchmarks/performance/node_rate.py [--seconds S] [--profile P] [--scenario S] [--rain MM_H] [--packets K]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

import yaml

from lidar_weather_sim.core.paths import config_dir


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=30.0, help="wall seconds measured after the first cloud")
    ap.add_argument("--profile", default="os1_128_2048")
    ap.add_argument("--scenario", default="highway_spray")
    ap.add_argument("--dirt", default="3l", help="cover sample (config/cover/samples.yaml)")
    ap.add_argument("--rain", type=float, default=10.0, help="rain intensity (mm/h)")
    ap.add_argument("--packets", type=float, default=32.0, help="spray drop packets per wheel per tick")
    ap.add_argument("--domain", type=int, default=199, help="ROS_DOMAIN_ID of the node and this process")
    ap.add_argument("--dds-profile", default=str(config_dir() / "fastdds_large_messages.xml"),
                    help="Fast DDS XML profile of both processes ('' = Fast DDS defaults)")
    args = ap.parse_args()
    os.environ.update(ROS_DOMAIN_ID=str(args.domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    if args.dds_profile:
        os.environ.update(FASTDDS_DEFAULT_PROFILES_FILE=args.dds_profile, FASTRTPS_DEFAULT_PROFILES_FILE=args.dds_profile)

    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import PointCloud2

    region_params = {"cover": {"texture": args.dirt}, "atmosphere": {"precipitation_type": "rain",
                     "intensity_mm_h": args.rain}, "spray": {"mist_packets_per_wheel_per_tick": args.packets}}  # fmt: skip
    params = {"scenario": args.scenario, "profile": args.profile, "pose_source": "scenario", "realtime_factor": 1.0,
              "time_step_s": 0.01, "regions": "[cover, atmosphere, spray]",
              "region_params": '"' + yaml.safe_dump(region_params, default_flow_style=True, width=10**6).strip() + '"'}  # fmt: skip
    cmd = [sys.executable, "-m", "lidar_weather_sim.ros.lidar_sim_node", "--ros-args"]
    for name, value in params.items():
        cmd += ["-p", f"{name}:={value}"]
    node_proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    rclpy.init()
    node = rclpy.create_node("node_rate_benchmark")
    clouds: list[tuple[float, int]] = []  # (wall s, stamp ns)
    clocks: list[tuple[float, int]] = []
    node.create_subscription(PointCloud2, "/lidar/points", lambda m: clouds.append(
        (time.monotonic(), m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)), qos_profile_sensor_data)  # fmt: skip
    node.create_subscription(Clock, "/clock", lambda m: clocks.append(
        (time.monotonic(), m.clock.sec * 10**9 + m.clock.nanosec)), QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))  # fmt: skip
    try:
        deadline = time.monotonic() + 300.0
        while not clouds and time.monotonic() < deadline and node_proc.poll() is None:
            rclpy.spin_once(node, timeout_sec=0.1)
        if not clouds:
            raise SystemExit(f"node_rate: no cloud from lidar_sim_node: {node_proc.stderr.read() if node_proc.poll() is not None else 'none within 300 s'}")
        start_wall, start_clock = clocks[-1] if clocks else clouds[0]
        first_cloud = len(clouds)
        end = start_wall + args.seconds
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
        end_wall, end_clock = clocks[-1]
    finally:
        node_proc.terminate()
        node_proc.wait(timeout=30)
        node.destroy_node()
        rclpy.shutdown()
    wall = end_wall - start_wall
    sim = (end_clock - start_clock) * 1e-9
    delivered = len(clouds) - first_cloud
    print(f"{args.profile}, {args.scenario}, regions cover ({args.dirt}) + atmosphere (rain {args.rain:g} mm/h) + "
          f"spray ({args.packets:g} packets), realtime_factor 1, DDS profile {args.dds_profile or 'defaults'}, "
          f"over {wall:.1f} s of wall time:")  # fmt: skip
    print(f"  simulated {sim:.2f} s: real-time factor achieved {sim / wall:.3f}")
    print(f"  clouds delivered: {delivered} ({delivered / max(sim, 1e-9):.2f} per simulated s, {delivered / wall:.2f} per wall s)")
    print(f"  lag behind real time at the end: {wall - sim:.2f} s")


if __name__ == "__main__":
    main()
