#!/usr/bin/env bash
# One-command, idempotent workspace setup for machines without a system ROS 2.
#
#   1. Debian packages (only when running as root and something is missing)
#   2. a venv in .venv with the pinned wheels of requirements.txt
#   3. the include-path fix for interface builds from the pip-installed rosidl,
#      sensor profiles and the real OS1-128 bag and mesh from the ouster-sdk sdist
#   4. tf2_msgs (compat/) built only where no tf2_msgs is importable
#   5. colcon build --symlink-install of src/
#   6. .venv/env.sh, which every make target sources
#
# Each step is skipped when its inputs have not changed (stamp files in .venv/).
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
venv="$root/.venv"
say() { printf '[setup] %s\n' "$*"; }

# --- 1. Debian packages ----------------------------------------------------
apt_packages=(python3-venv python3-dev cmake g++ make libusb-1.0-0 libgomp1 libllvm15 chromium)  # chromium: render --html test
missing=()
for p in "${apt_packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  if [[ $(id -u) -eq 0 ]]; then
    say "installing Debian packages: ${missing[*]}"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  else
    say "missing Debian packages (run as root or install them): ${missing[*]}"
  fi
fi

# --- 2. venv with pinned wheels --------------------------------------------
python_bin="${PYTHON:-python3}"
if [[ ! -x "$venv/bin/python" ]]; then
  say "creating venv $venv"
  "$python_bin" -m venv "$venv"
fi
req_hash=$(sha256sum requirements.txt | cut -c1-16)
if [[ "$(cat "$venv/.requirements.stamp" 2>/dev/null)" != "$req_hash" ]]; then
  say "installing pinned Python packages (requirements.txt)"
  "$venv/bin/pip" install --quiet --disable-pip-version-check -r requirements.txt
  echo "$req_hash" >"$venv/.requirements.stamp"
  rm -f "$venv/.cmake-fix.stamp"
fi

# --- 3. include paths baked into the wheels' cmake exports ------------------
if [[ ! -f "$venv/.cmake-fix.stamp" ]]; then
  py_inc=$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
  np_inc=$("$venv/bin/python" -c 'import numpy; print(numpy.get_include())')
  say "rewriting /opt/python include paths -> $py_inc, $np_inc"
  { grep -rlZ --include='*.cmake' '/opt/python/cp3' "$venv/share" 2>/dev/null || true; } |
    xargs -0 -r sed -i -E \
      -e "s#/opt/python/cp3[0-9]+-cp3[0-9]+/lib/python3\.[0-9]+/site-packages/numpy/_core/include#$np_inc#g" \
      -e "s#/opt/python/cp3[0-9]+-cp3[0-9]+/include/python3\.[0-9]+#$py_inc#g"
  touch "$venv/.cmake-fix.stamp"
fi

# --- 3b. sensor profiles generated from measured calibrations ------------------
ouster_sdist="$venv/cache/ouster_sdk-1.0.1.tar.gz"
if [[ ! -f "$ouster_sdist" ]]; then
  say "downloading the ouster-sdk 1.0.1 sdist (OS1-128 beam angles of its test recordings)"
  mkdir -p "$venv/cache"
  "$venv/bin/pip" download --quiet --no-deps --no-binary ouster-sdk ouster-sdk==1.0.1 -d "$venv/cache"
fi
if [[ ! -f config/sensors/os1_128_2048.yaml || scripts/make_sensor_profiles.py -nt config/sensors/os1_128_2048.yaml ]]; then
  say "generating Velodyne and Ouster profiles in config/sensors/"
  "$venv/bin/python" scripts/make_sensor_profiles.py "$ouster_sdist" config/sensors >/dev/null
fi

# --- 3c. the real OS1-128 recording of the sdist as a bag and a street mesh ----
# (lidar-weather-sim import-ouster; redone when the importer changes)
ouster_real="$venv/cache/ouster_real"
import_hash=$(cd src/lidar_weather_sim/lidar_weather_sim && cat io/ouster_import.py io/ouster_pcap.py core/points.py | sha256sum | cut -c1-16)
if [[ "$(cat "$ouster_real/.stamp" 2>/dev/null)" != "$import_hash" ]]; then
  say "importing the real OS1-128 recording into $ouster_real"
  rm -rf "$ouster_real"
  PYTHONPATH="$root/src/lidar_weather_sim" "$venv/bin/python" -m lidar_weather_sim.cli import-ouster \
    --sdist "$ouster_sdist" --out "$ouster_real/os1_128_street" --mesh-out "$ouster_real/os1_128_street_mesh.ply" >/dev/null
  echo "$import_hash" >"$ouster_real/.stamp"
fi

# --- 4/5. colcon builds -----------------------------------------------------
mkdir -p log
export VIRTUAL_ENV="$venv"
export PATH="$venv/bin:$PATH"
export AMENT_PREFIX_PATH="$venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export CMAKE_PREFIX_PATH="$venv${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
export PYTHONNOUSERSITE=1
colcon_common=(--event-handlers console_direct- --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$venv/bin/python")

if python -c 'import tf2_msgs.msg' 2>/dev/null && [[ ! -d install/compat/tf2_msgs ]]; then
  say "tf2_msgs provided by the environment; not building the compat package"
elif [[ ! -f install/compat/.built ]] || [[ compat/tf2_msgs -nt install/compat/.built ]]; then
  say "building compat/tf2_msgs (TFMessage, identical definition)"
  colcon --log-base log/compat build --base-paths compat/tf2_msgs \
    --build-base build/compat --install-base install/compat --merge-install \
    "${colcon_common[@]}" >log/compat_build.txt 2>&1 ||
    { cat log/compat_build.txt; say "tf2_msgs compat build failed"; exit 1; }
  touch install/compat/.built
fi

src_stamp=$(find src -name package.xml -o -name setup.py -o -name setup.cfg | sort | xargs cat | sha256sum | cut -c1-16)
if [[ "$(cat install/.src.stamp 2>/dev/null)" != "$src_stamp" ]]; then
  say "colcon build --symlink-install (src/)"
  if [[ -f install/compat/local_setup.bash ]]; then
    # shellcheck disable=SC1091
    set +u; source install/compat/local_setup.bash; set -u
  fi
  colcon build --base-paths src --symlink-install "${colcon_common[@]}" >log/colcon_build.txt 2>&1 ||
    { cat log/colcon_build.txt; say "colcon build failed"; exit 1; }
  echo "$src_stamp" >install/.src.stamp
fi

# --- 6. env script -----------------------------------------------------------
cat >"$venv/env.sh" <<EOF
# Generated by scripts/setup.sh: source it to use the workspace without a system ROS.
export VIRTUAL_ENV="$venv"
export PATH="$venv/bin:\$PATH"
export AMENT_PREFIX_PATH="$venv\${AMENT_PREFIX_PATH:+:\$AMENT_PREFIX_PATH}"
export PYTHONNOUSERSITE=1
export LWS_WORKSPACE="$root"
_lws_nounset=\$(set +o | grep nounset); set +u
[ -f "$root/install/compat/local_setup.bash" ] && . "$root/install/compat/local_setup.bash"
. "$root/install/local_setup.bash"
eval "\$_lws_nounset"; unset _lws_nounset
EOF
say "ready: source .venv/env.sh"
