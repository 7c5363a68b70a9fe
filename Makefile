# Two entry points: `make demo` (set up, run the main job) and `make test`
# (set up, lint, check the import layers, type-check, run the test suite). Both create .venv on first use.
# `make check` is the inner loop: the same checks and the unit tests on parallel workers, less
# the few that assert real-time bounds (marked `timing`: they run in `make test`).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: setup demo test check lint typecheck clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/fedlab demo

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports

typecheck: $(STAMP)
	$(BIN)/mypy

# The suite in three passes, each always run (either failing fails the target): the unit
# tests on parallel workers (pure logic and short-lived processes), then the integration
# tests one at a time (real routers and agents whose sync and timing claims assume the
# cores are theirs), then the unit tests marked `timing` (a closed loop on real time).
WORKERS ?= 4

test: lint typecheck
	$(BIN)/pytest tests/unit -n $(WORKERS) --dist worksteal -m "not timing"; unit=$$?; \
	$(BIN)/pytest tests/integration; integration=$$?; \
	$(BIN)/pytest tests/unit -m timing; timing=$$?; \
	[ $$unit = 0 ] && [ $$integration = 0 ] && [ $$timing = 0 ]

check: lint typecheck
	$(BIN)/pytest tests/unit -n auto -m "not timing" -q

clean:
	rm -rf $(VENV) runs .mypy_cache .ruff_cache .pytest_cache
