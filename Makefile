# Two commands set everything up on a fresh machine: `make run` and `make test`.
# Both create .venv and install the project into it on first use.

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
OUT ?= runs/driver-emgail
SEEDS ?= 4
ITERATIONS ?= 400

.PHONY: run test test-slow lint format bench bench-envs bench-check check-envs separability sweep experts clean

# --no-compile: Python byte-compiles the modules it imports when it first imports them, not every
# file of every dependency at install.
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --no-compile -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)
	$(PY) -m emgail_jax.run --env driver --algo emgail --seeds $(SEEDS) \
		--iterations $(ITERATIONS) --out $(OUT) --overwrite

test: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder

test-slow: $(STAMP)
	$(PY) -m pytest -q -m slow

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

format: $(STAMP)
	$(VENV)/bin/ruff format .
	$(VENV)/bin/ruff check --fix .

# Where the time goes (driver-2 and halfcheetah-3): per seed-iteration, per piece, compile
# (cold and warm cache), memory, and against native MuJoCo and the reference implementation.
bench: $(STAMP)
	$(PY) experiments/bench.py

# Env-steps/s of every env, batched, against native MuJoCo on both cores, as ratios.
bench-envs: $(STAMP)
	$(PY) experiments/bench_env_throughput.py

# The reward check's fresh TRPO scored every 10th iteration (as shipped) against every one;
# then its seeds in one process against a process per seed at once, as the sweep runs them.
bench-check: $(STAMP)
	$(PY) experiments/bench_reward_check.py
	$(PY) experiments/bench_check_processes.py

# The MJX envs' fast solver settings against native MuJoCo's defaults: open-loop gaits, then
# the shipped experts' closed-loop behaviour.
check-envs: $(STAMP)
	$(PY) experiments/check_mjx_dynamics.py
	$(PY) experiments/check_expert_replay.py

separability: $(STAMP)
	$(PY) experiments/driver_separability.py

# The paper's Tables 2-3 and Figures 4-6, cell by cell into OUT/runs; stop and start at
# will: finished cells are skipped, an interrupted one resumed. ONLY=fig5a, ONLY=hopper-3, ...
# OUT defaults to results here (given on the command line, it wins). ENGINE=ray runs every
# cell as a Ray task, on a Ray started here or on the cluster at RAY_ADDRESS=HOST:PORT.
SWEEP_OUT := $(if $(filter command line environment,$(origin OUT)),$(OUT),results)
ENGINE ?= local
sweep: $(STAMP)
	$(PY) experiments/sweep.py --seeds $(SEEDS) --iterations $(ITERATIONS) --out $(SWEEP_OUT) \
		$(if $(ONLY),--only '$(ONLY)') --engine $(ENGINE) \
		$(if $(RAY_ADDRESS),--ray-address $(RAY_ADDRESS))

# Retrains every MJX env's experts and rewrites the shipped demonstrations (emgail_jax/data).
experts: $(STAMP)
	for env in swimmer hopper halfcheetah reacher; do \
		$(PY) -m emgail_jax.experts --env $$env || exit 1; \
	done

clean:
	rm -rf runs .cache
