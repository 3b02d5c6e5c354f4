# Two commands on a fresh machine with python3 and make: `make run` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test test-fast test-kinematic lint fuzz bench soak soak-day compose-bench compose-soak stress profile secrets clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[all,test,lint]'
	touch $(STAMP)

run: $(STAMP)  ## the whole loop: router, sim, motor, odometry, localization, drive, then a report
	$(BIN)/invent up

TEST_WORKERS ?= 2

test: test-fast  ## the whole suite (but the benchmarks' own smoke: make bench-smoke): test-fast, then the loop's runs one at a time
	$(BIN)/python -m pytest -m "slow and not bench_smoke" --durations=25

test-fast: $(STAMP)  ## the suite without the end-to-end runs of the whole loop (the edit-test loop), over TEST_WORKERS processes
	$(BIN)/python -m pytest -m "not slow and not bench_smoke" -n $(TEST_WORKERS)

test-kinematic: $(STAMP)  ## the loop's end-to-end tier on the kinematic engine (no physics): the square, determinism, bumps, a fleet
	$(BIN)/python -m pytest -m kinematic

lint: $(STAMP)  ## ruff (lint and format) on everything, mypy on schemas/ services/ sim_bridge/ examples/
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

fuzz: $(STAMP)  ## 10^4 generated bad payloads per consumed key and queryable into the running services, the goal, sensor and ROS action surfaces too -> runs/fuzz.json, runs/fuzz-goals.json
	mkdir -p runs
	INVENT_FUZZ_PAYLOADS=10000 INVENT_FUZZ_FIGURES=runs/fuzz.json $(BIN)/python -m pytest tests/test_fuzz.py tests/test_fuzz_goals.py -q -s -p no:cacheprovider

bench: $(STAMP)  ## benchmarks/ -> benchmarks/results/latest.json, not committed (never part of `make test`)
	$(BIN)/python -m benchmarks

bench-smoke: $(STAMP)  ## every benchmark section with --quick, checking every field is written (a minute and more; run it after changing benchmarks/)
	$(BIN)/python -m pytest -m bench_smoke tests/test_benchmarks_smoke.py

soak: $(STAMP)  ## the stack left running an hour (DURATION=3600): memory, open files, health -> benchmarks/results/soak.json
	$(BIN)/python -m benchmarks.soak --duration $(or $(DURATION),3600)

soak-day: $(STAMP)  ## 24 simulated hours of errands (SIM_HOURS=24) in one composed lockstep run, faults injected on a schedule -> benchmarks/results/soak_day.json
	$(BIN)/python -m benchmarks.soak_day --sim-hours $(or $(SIM_HOURS),24)

compose-bench: $(STAMP)  ## the sim's late steps bare and under docker compose, one cause at a time (Docker and `make secrets`; skipped, saying so, without Docker) -> benchmarks/results/compose.json
	$(BIN)/python -m benchmarks.compose $(ARGS)

compose-soak: $(STAMP)  ## docker compose up left running an hour (DURATION=3600), the control path's container killed twice mid-run (ARGS=--split: the motor's, then the sim's) -> benchmarks/results/compose-soak.json
	$(BIN)/python -m benchmarks.compose_soak --duration $(or $(DURATION),3600) $(ARGS)

stress: $(STAMP)  ## `invent up --no-record` started and stopped 100 times in a row (STARTS=100): every start must succeed
	$(BIN)/python -m benchmarks.stress_starts --starts $(or $(STARTS),100)

profile: $(STAMP)  ## where each process of the lockstep loop spends its time (py-spy; ARGS=--composed for one process)
	$(BIN)/python -m pip install --quiet py-spy
	$(BIN)/python -m benchmarks.profile $(ARGS)

secrets: $(STAMP)  ## fresh credentials for `docker compose up`, in docker/secure/secrets/ (never committed)
	PATH="$(CURDIR)/$(BIN):$$PATH" INVENT_WITH="$(WITH)" docker/secure/make-secrets

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis
