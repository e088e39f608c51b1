#!/usr/bin/env bash
# The README demo: the CLI, then a PointCloud2 published by one process and
# received by another over real DDS.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
# shellcheck disable=SC1091
source .venv/env.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-42}"
export ROS_LOG_DIR="$root/log/ros"

echo "== lidar-weather-sim --help"
lidar-weather-sim --help
echo
out="$root/log/demo/highway_clear"
echo "== simulate 2 s of the thesis' highway set-up (scala4, 25 Hz) into $out"
lidar-weather-sim run highway_clear --frames 50 --out "$out" --overwrite
lidar-weather-sim info "$out" | head -12
echo
echo "== process 1: pattern_node publishes a synthetic sweep on /lidar/points at 10 Hz"
lidar-weather-sim pattern --rate 10 --count 100 &
publisher=$!
trap 'kill -INT $publisher 2>/dev/null || true; wait $publisher 2>/dev/null || true' EXIT
echo "== process 2: lidar-weather-sim listen receives 5 clouds"
lidar-weather-sim listen --count 5 --timeout 30
echo "== demo done"
