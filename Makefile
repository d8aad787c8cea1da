# Two commands on a fresh machine:  make run   |   make test
# Both first run tools/bootstrap.sh, which installs whatever is missing (idempotent).
SHELL := /bin/bash
PY := .venv/bin/python
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export PYTHONDONTWRITEBYTECODE :=

SEED ?= 1
# Empty: the default scenario of `vesselbot run` / `simulate` (sound_small_artery: the paper's Section III-C
# scenario with the physically sound readings, docs/reproduction.md); the as-printed variant:
# make run CONFIG=paper_small_artery  (a shipped name, see `vesselbot scenarios`, or a path)
CONFIG ?=
PYTEST_ARGS ?=

.PHONY: bootstrap bootstrap-run run lint test test-unit test-integration bench simulate figures clean

bootstrap:
	@tools/bootstrap.sh test

## What `make run` needs only (no test tools; the numba warm-up of the default scenario, the rest on first use).
bootstrap-run:
	@tools/bootstrap.sh run

## The main job: the paper's closed-loop scenario over ROS 2, recorded to runs/, then reported.
run: bootstrap-run
	@$(PY) -m vesselbot_ros.cli run $(if $(CONFIG),--config $(CONFIG)) --seed $(SEED) --report

## The whole test suite (unit + integration over real ROS 2 topics), on two workers (each test leases its
## own ROS domain; a module's tests stay on one worker, so its module fixtures run once).  The tests that
## bound wall time tightly (marker `wallclock`: real-time runs, process-exit deadlines, replay timing) run alone, last.
INTEGRATION = $(PY) -m pytest test/integration -q -n 2 --dist loadfile -m "not wallclock" --durations=8 $(PYTEST_ARGS) \
	&& $(PY) -m pytest test/integration -q -m wallclock --durations=4 $(PYTEST_ARGS)
## The live view's unit tests (a Foxglove server, native code) run in a fresh process of their own, as the
## live view does in use (the recorder node, `vesselbot replay --live`): after half the unit suite in one
## worker, that worker was seen to die at the server's first test (2 of 6 clean-clone runs; never alone).
UNIT = $(PY) -m pytest test/unit -q -n 2 --ignore=test/unit/test_live.py --durations=10 $(PYTEST_ARGS) \
	&& $(PY) -m pytest test/unit/test_live.py -q $(PYTEST_ARGS)
## (the bootstrap runs `make lint`'s checks while numba's warm-up finishes: VESSELBOT_BOOTSTRAP_LINT).
## The suite's two workers fill the two cores: numba's parallel loops run on one thread in each, and OpenMP's idle
## threads sleep instead of spinning (a sixth less wall time; the results do not depend on the thread count, which
## test_builds_fingerprint checks at one and two threads).
test test-unit test-integration: export NUMBA_NUM_THREADS = 1
test test-unit test-integration: export OMP_WAIT_POLICY = PASSIVE
test:
	@VESSELBOT_BOOTSTRAP_LINT='$(LINT)' tools/bootstrap.sh test
	@$(UNIT) && $(INTEGRATION)

## Static checks (configuration in pyproject.toml): ruff over the code, tests and tools, then mypy over the
## package (incremental, cache in .mypy_cache: a few seconds when little changed).  `make test` runs it first.
LINT = $(PY) -m ruff check --quiet vesselbot_ros test tools bench examples && $(PY) -m mypy
lint: bootstrap
	@$(LINT)

test-unit: bootstrap
	@$(UNIT)

test-integration: bootstrap
	@$(INTEGRATION)

## ROS-free closed loop of the same scenario.
simulate: bootstrap-run
	@$(PY) -m vesselbot_ros.cli simulate $(if $(CONFIG),--config $(CONFIG)) --seed $(SEED)

## Paper figures 7 and 8.
figures: bootstrap-run
	@$(PY) -m vesselbot_ros.cli design-map && $(PY) -m vesselbot_ros.cli force-balance && $(PY) -m vesselbot_ros.cli sensitivity

bench: bootstrap
	@for b in bench/bench_*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

clean:
	rm -rf build .venv out
