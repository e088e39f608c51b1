#!/usr/bin/env bash
# The README demo: an offline run into a bag, then the closed loop over real DDS
# (adaptive cruise with and without the weather filter, with and without a box).
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
echo "== closed loop over DDS: lidar_sim_node -> [weather_filter_node] -> ego_controller_node -> /ego/cmd_speed"
echo "   highway_spray_crosswind (rain 2 mm/h, spray blowing across the lane): without the filter the rain"
echo "   ahead reads as an obstacle and the ego brakes; with it, not; a real box brakes both (4 runs, ~1 min)"
report="$root/log/demo/closed_loop"
lidar-weather-sim closed-loop --seconds 4 --box-at 1.0 --out "$report"
cat "$report/report.md"
echo "== demo done (speed traces: $report/speed.png)"
