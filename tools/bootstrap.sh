#!/usr/bin/env bash
# Idempotent setup of everything `make run` and `make test` need, from nothing:
#   1. .venv with the pinned requirements (ROS 2 Jazzy wheels, numpy, scipy, ...): the numerics first, the rest
#      (1b) while the warm-up compiles
#   2. vesselbot_ros installed in editable mode
#   3. msg_defs/ (vesselbot_msgs) and third_party/simulation_interfaces built with rosidl into .venv
#   4. numba cache of the compiled stages and loop warmed (vesselbot_ros.numba_cache), in the
#      background from step 2 on (one core; the interface builds take the other)
#   5. tools/js: Foxglove's own JavaScript readers and clients (npm ci from the committed lock file),
#      which the integration tests run with node
#   6. optional extras named in VESSELBOT_EXTRAS (learn: requirements-learn.txt), while the warm-up compiles
# Each step is skipped when the sha256 of its inputs matches the stamp it left,
# so a second call does nothing (well under 5 s).  A failing step leaves no stamp.
# Usage: tools/bootstrap.sh [test|run]   test (default): everything make test needs;
#   run: what make run needs only (no tools/js; the numba warm-up of the default scenario, the rest compiles on
#   first use, a 3-D tree's wall build saying so in one line)
set -euo pipefail
scope=${1:-test}
case $scope in test|run) ;; *) echo "vesselbot bootstrap: unknown scope '$scope' (test or run)" >&2; exit 2;; esac
cd "$(dirname "$0")/.."
root=$PWD
venv=$root/.venv
py=${PYTHON:-python3}
stamps=$venv/.vesselbot-stamps

hash_files() { cat "$@" | sha256sum | cut -d' ' -f1; }
fresh() { [ -f "$stamps/$1" ] && [ "$(cat "$stamps/$1")" = "$2" ]; }
quiet_pip() {  # pip without the local index's noise; fails when pip fails
  local out rc=0
  out=$("$venv/bin/python" -m pip --disable-pip-version-check -q "$@" 2>&1) || rc=$?
  [ -z "$out" ] || grep -v "is ignored: it is neither a file nor a directory" <<<"$out" || true
  if [ $rc -ne 0 ]; then echo "vesselbot bootstrap: pip $1 failed (exit $rc)" >&2; exit $rc; fi
}
mark() { mkdir -p "$stamps"; echo "$2" > "$stamps/$1"; }
# every step that runs says how long it took, and the bootstrap its total, so that the next fresh machine
# knows what to expect (the figures in docs/install.md are such lines, from a fresh clone)
t0=$SECONDS
step_t0=$SECONDS
step() { step_t0=$SECONDS; echo "vesselbot bootstrap: $*"; }
took() { echo "vesselbot bootstrap:   $1 took $((SECONDS - step_t0)) s"; }

for tool in cmake ninja cc; do
  command -v $tool >/dev/null || { echo "vesselbot bootstrap: '$tool' is required (apt-get install cmake ninja-build gcc)" >&2; exit 1; }
done
[ "$scope" = run ] || for tool in node npm; do
  command -v $tool >/dev/null || { echo "vesselbot bootstrap: '$tool' is required (apt-get install nodejs npm)" >&2; exit 1; }
done

# 1. virtual environment + pinned requirements, in two parts: first the numerics the numba warm-up needs
#    (WARM_REQS: it starts as soon as they and the package are in), then the rest (the ROS 2 wheels, bags, tables,
#    tests: half of pip's time), installed while the warm-up compiles (1b, below)
WARM_REQS='^(numpy|scipy|numba|llvmlite|PyYAML|matplotlib|gmsh|scikit-fem|pyamg|gymnasium|farama-notifications|tqdm|setuptools|wheel)=='
req=$(hash_files requirements.txt)
need_reqs=
if ! fresh requirements "$req" || [ ! -x "$venv/bin/python" ]; then
  need_reqs=1
  step "installing the pinned numerics into .venv (pip; the rest follows while numba compiles)"
  [ -x "$venv/bin/python" ] || "$py" -m venv "$venv"
  rm -f "$stamps/requirements" "$stamps/interfaces" "$stamps/sim-interfaces" "$stamps/package"
  warm_reqs=$(mktemp)
  grep -E "$WARM_REQS" requirements.txt >"$warm_reqs"
  quiet_pip install -r "$warm_reqs"
  rm -f "$warm_reqs"
  took "pip install (numerics)"
fi

# 2. vesselbot_ros itself, editable (before the interfaces: it needs none of them, and the numba warm-up needs it)
# the console scripts derive from the graph spec
pkg=$(hash_files setup.py setup.cfg package.xml requirements.txt vesselbot_ros/graph_spec.py)
if ! fresh package "$pkg"; then
  step "installing vesselbot_ros (editable)"
  quiet_pip install --no-deps --no-build-isolation -e .
  (cd / && "$venv/bin/python" -c "import vesselbot_ros.cli") || { echo "vesselbot bootstrap: vesselbot_ros does not import" >&2; exit 1; }
  mark package "$pkg"
  took "vesselbot_ros"
fi

# 4. numba's on-disk cache, compiled once per version of the compiled sources, so that `make run`,
#    `make test` and every node start without compiling (vesselbot_ros.numba_cache drops caches
#    of other code on import; this only warms them).  Minutes on a fresh machine (the 3-D trees' wall fields): it runs in the
#    background while the interfaces build (it needs none of them), make test's three parts (planar, 3-D, and the
#    3-D wall's build, its own process when the trees' lookups are cached: the 3-D part is the longest) in a process
#    each, and is waited for before the bootstrap ends.
nb=$(hash_files requirements.txt $(grep -rl --include='*.py' numba vesselbot_ros | LC_ALL=C sort))
numba_pids=()
numba_logs=()
warm_scopes=(planar trees wall_build); numba_stamp=numba-cache  # make test: its three parts at once, a process each
[ "$scope" = test ] || { warm_scopes=(run); numba_stamp=numba-run; }
if ! fresh numba-cache "$nb" && ! fresh "$numba_stamp" "$nb"; then
  echo "vesselbot bootstrap: compiling the closed loop into numba's cache (${warm_scopes[*]}: once per version of the code, in the background)"
  rm -f "$stamps/$numba_stamp"
  for ws in "${warm_scopes[@]}"; do
    log=$(mktemp)
    # every core for numba's parallel loops (make test pins one thread per test worker; the 3-D trees' wall
    # fields are built here, in parallel loops, minutes on one thread; their bits do not depend on the count)
    # make test's planar and 3-D parts warm the Gymnasium environments' kernel too, after their loops (vesselbot_ros.envs.warm)
    warm_module=vesselbot_ros.sim.warm; case $ws in planar|trees) warm_module="vesselbot_ros.envs.warm --loops";; esac
    (cd / && exec env -u NUMBA_NUM_THREADS "$venv/bin/python" -m $warm_module --scope "$ws" --no-progress) >"$log" 2>&1 &
    numba_pids+=($!); numba_logs+=("$log")
  done
  numba_t0=$SECONDS
fi
numba_done() {  # wait for the background warm-ups; stamp them, or show the first error and fail
  [ ${#numba_pids[@]} -gt 0 ] || return 0
  echo "vesselbot bootstrap: waiting for the numba warm-up (started $((SECONDS - numba_t0)) s ago)"
  local i failed=
  for i in "${!numba_pids[@]}"; do
    if ! wait "${numba_pids[$i]}"; then
      [ -n "$failed" ] || { tail -30 "${numba_logs[$i]}" >&2; failed=1; }
    fi
  done
  rm -f "${numba_logs[@]}"; numba_pids=()
  [ -z "$failed" ] || { echo "vesselbot bootstrap: numba warm-up failed" >&2; exit 1; }
  mark "$numba_stamp" "$nb"
  echo "vesselbot bootstrap:   numba warm-up took $((SECONDS - numba_t0)) s (in the background)"
}
trap '[ ${#numba_pids[@]} -eq 0 ] || kill "${numba_pids[@]}" 2>/dev/null; true' EXIT

# 1b. the rest of the pinned requirements (the interfaces below need the ROS 2 wheels)
if [ -n "$need_reqs" ]; then
  step "installing the rest of the pinned requirements into .venv (pip, while numba compiles)"
  quiet_pip install -r requirements.txt
  "$venv/bin/python" -c "import rclpy, numpy, scipy, numba, rosbags, mcap, dask, distributed, pyarrow, foxglove, gymnasium" \
    || { echo "vesselbot bootstrap: requirements did not install" >&2; exit 1; }
  "$venv/bin/python" -c "import skfem, gmsh" \
    || { echo "vesselbot bootstrap: gmsh's wheel needs the system libraries libGLU, libXcursor, libXft and libXinerama" \
              "(apt-get install libglu1-mesa libxcursor1 libxft2 libxinerama1)" >&2; exit 1; }
  mark requirements "$req"
  took "pip install (the rest)"
fi

# 3. interfaces (rebuilt when any .msg/.srv/CMakeLists/package.xml changes)
ifc=$(hash_files requirements.txt cmake/*.cmake tools/build_interfaces.sh \
      $(find msg_defs -type f | LC_ALL=C sort))
if ! fresh interfaces "$ifc"; then
  step "building msg_defs (vesselbot_msgs) into .venv (rosidl)"
  rm -f "$stamps/interfaces"
  tools/build_interfaces.sh "$venv" msg_defs build/msg_defs
  mark interfaces "$ifc"
  took "msg_defs"
fi

# 3b. the simulation_interfaces standard (vendored, unchanged; no Jazzy wheel of it on PyPI)
sif=$(hash_files requirements.txt cmake/*.cmake tools/build_interfaces.sh \
      $(find third_party/simulation_interfaces -type f \( -name '*.msg' -o -name '*.srv' -o -name '*.action' \
           -o -name CMakeLists.txt -o -name package.xml \) | LC_ALL=C sort))
if ! fresh sim-interfaces "$sif"; then
  step "building third_party/simulation_interfaces into .venv (rosidl)"
  rm -f "$stamps/sim-interfaces"
  tools/build_interfaces.sh "$venv" third_party/simulation_interfaces build/simulation_interfaces
  mark sim-interfaces "$sif"
  took "simulation_interfaces"
fi

# 5. Foxglove's JavaScript packages for the tests (exact versions from tools/js/package-lock.json)
js=$(hash_files tools/js/package.json tools/js/package-lock.json)
if [ "$scope" = test ] && { ! fresh npm "$js" || [ ! -d tools/js/node_modules ]; }; then
  step "installing tools/js (npm ci)"
  rm -f "$stamps/npm"
  (cd tools/js && npm ci --no-audit --no-fund --loglevel=error) || { echo "vesselbot bootstrap: npm ci in tools/js failed" >&2; exit 1; }
  mark npm "$js"
  took "npm ci"
fi

# 6. optional extras, asked for by name (VESSELBOT_EXTRAS=learn: requirements-learn.txt, the learned baseline's
#    stable-baselines3 and torch; .ci/run asks for it so that the PPO smoke test runs; make run never needs it)
for extra in ${VESSELBOT_EXTRAS:-}; do
  case $extra in
    learn) xreq=requirements-learn.txt ;;
    *) echo "vesselbot bootstrap: unknown extra '$extra' in VESSELBOT_EXTRAS (known: learn)" >&2; exit 2 ;;
  esac
  xh=$(hash_files requirements.txt "$xreq")
  if ! fresh "extra-$extra" "$xh"; then
    step "installing the optional '$extra' extra ($xreq)"
    rm -f "$stamps/extra-$extra"
    quiet_pip install -r "$xreq"
    mark "extra-$extra" "$xh"
    took "the '$extra' extra"
  fi
done

# make test's static checks (the Makefile's LINT, passed as VESSELBOT_BOOTSTRAP_LINT), run while the numba
# warm-up may still be compiling: they need the package and the interfaces, not the cache; a finding fails after it
lint_rc=0
if [ -n "${VESSELBOT_BOOTSTRAP_LINT:-}" ]; then
  bash -c "$VESSELBOT_BOOTSTRAP_LINT" || lint_rc=$?
fi
numba_done
[ $((SECONDS - t0)) -lt 5 ] || echo "vesselbot bootstrap: done in $((SECONDS - t0)) s"
[ "$lint_rc" -eq 0 ] || { echo "vesselbot bootstrap: lint failed (ruff or mypy, above)" >&2; exit "$lint_rc"; }
