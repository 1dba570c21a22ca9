# Two commands set everything up on a fresh machine: `make run` and `make test`.
# Both create .venv and install the project into it on first use.

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
OUT ?= runs/driver-emgail
SEEDS ?= 4
ITERATIONS ?= 400

.PHONY: run test test-slow lint format bench separability experts clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)
	$(PY) -m emgail_jax.run --env driver --algo emgail --seeds $(SEEDS) \
		--iterations $(ITERATIONS) --out $(OUT) --overwrite

test: $(STAMP)
	$(PY) -m pytest -q

test-slow: $(STAMP)
	$(PY) -m pytest -q -m slow

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

format: $(STAMP)
	$(VENV)/bin/ruff format .
	$(VENV)/bin/ruff check --fix .

bench: $(STAMP)
	$(PY) experiments/bench_driver.py

separability: $(STAMP)
	$(PY) experiments/driver_separability.py

# Retrains every MJX env's experts and rewrites the shipped demonstrations (emgail_jax/data).
experts: $(STAMP)
	for env in swimmer hopper halfcheetah reacher; do \
		$(PY) -m emgail_jax.experts --env $$env || exit 1; \
	done

clean:
	rm -rf runs .cache
