#!/usr/bin/env bash
# Build a rosidl interface package (msg_defs/ = vesselbot_msgs, third_party/simulation_interfaces)
# against the ROS 2 PyPI wheels in a venv, and install it into that venv's prefix.
#
# usage: tools/build_interfaces.sh VENV SRC_DIR BUILD_DIR [--no-install]
#
# Only the C and Python type supports are generated and compiled (cmake/python_typesupports_only.cmake):
# rclpy uses those alone, the wheels carry no rclcpp, and the C++ ones were 60 % of the compile time.
#
# Fails (non-zero) with the cmake/rosidl error printed if a .msg/.srv is broken.
# The previous install is only replaced after a successful build, and is removed
# through cmake's install_manifest.txt (cmake --install is invisible to pip).
set -euo pipefail
venv=$(cd "$1" && pwd); src=$(cd "$2" && pwd); build=$3; install=yes
[ "${4:-}" = "--no-install" ] && install=no
here=$(cd "$(dirname "$0")/.." && pwd)
py="$venv/bin/python3"
log="$build.log"
mkdir -p "$build"

# A different venv's bootstrapper may have set these; cmake must see ours only.
unset _ROS_WHEELS_BOOTSTRAP_COMPLETE LD_LIBRARY_PATH || true
export AMENT_PREFIX_PATH="$venv" PATH="$venv/bin:$PATH"

run() {  # run a step; on failure show the tool's own error and stop
  local what=$1; shift
  if ! "$@" >"$log" 2>&1; then
    echo "vesselbot bootstrap: $what of interfaces in $src FAILED:" >&2
    # rosidl/cmake errors: show the error block, then the tail for context
    grep -nE -A12 "(Error|error:|ERROR|Traceback|Could not|Invalid|invalid)" "$log" | head -60 >&2 || true
    echo "--- last lines of $log ---" >&2
    tail -25 "$log" >&2
    exit 1
  fi
}

run "cmake configure" cmake -S "$src" -B "$build" -G Ninja \
  -DCMAKE_PREFIX_PATH="$venv" -DCMAKE_INSTALL_PREFIX="$venv" \
  -DPython3_EXECUTABLE="$py" -DBUILD_TESTING=OFF \
  -DCMAKE_PROJECT_INCLUDE="$here/cmake/fix_wheel_include_paths.cmake" \
  -DCMAKE_PROJECT_TOP_LEVEL_INCLUDES="$here/cmake/python_typesupports_only.cmake"
run "build" cmake --build "$build" -j "$(nproc)"
[ $install = yes ] || exit 0

pkg=$(sed -n 's:.*<name>\(.*\)</name>.*:\1:p' "$src/package.xml" | head -1)
manifest="$venv/share/$pkg/.install_manifest.txt"
if [ -f "$manifest" ]; then            # uninstall the previous interface build
  while IFS= read -r f; do [ -n "$f" ] && rm -f "$f"; done < "$manifest"
fi
run "install" cmake --install "$build"
cp "$build/install_manifest.txt" "$manifest"
"$py" -c "import $pkg.msg, $pkg.srv" || {
  echo "vesselbot bootstrap: $pkg installed but does not import" >&2; exit 1; }
