# Two entry points: `make demo` (set up, run the main job) and `make test`
# (set up, lint, check the import layers, type-check, run the test suite). Both create .venv on first use.
# `make check` is the inner loop: the same checks and the unit tests on parallel workers, less
# the few that assert real-time bounds (marked `timing`: they run in `make test`).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: setup demo test check lint typecheck docs clean

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
	$(MAKE) docs

# The user guide (mkdocs.yml, docs/) as a site in .site/; --strict: a broken link or
# anchor fails the build, and so `make lint` and `make test`.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir .site

typecheck: $(STAMP)
	$(BIN)/mypy

# The suite in two passes, both always run (either failing fails the target). First every
# test not marked `timing`: those marked `testbed` one after another in a lane of their own
# (one network testbed runs on a host at a time; their lab processes run ahead of the
# rest), beside the others on parallel workers; the lane's output follows the workers'.
# Then the `timing` tests one at a time (real-time bounds on a closed loop, an abort's
# latency, a start's spread: claims about processes that have the cores to themselves).
# Sync accuracy is judged against the bound each estimate states in the same run, so it
# holds on shared cores.
WORKERS ?= 4
LANE := .testbed-lane

test: lint typecheck
	rm -rf $(LANE) && mkdir -p $(LANE)
	$(BIN)/pytest tests -m "testbed and not timing" -p no:cacheprovider \
		--basetemp=$(LANE)/tmp > $(LANE)/log 2>&1 & lane=$$!; \
	$(BIN)/pytest tests -n $(WORKERS) --dist worksteal -m "not timing and not testbed"; \
	parallel=$$?; wait $$lane; testbed=$$?; \
	echo "--- the testbed lane (pytest -m 'testbed and not timing') ---"; cat $(LANE)/log; \
	$(BIN)/pytest tests -m timing; timing=$$?; \
	[ $$parallel = 0 ] && [ $$testbed = 0 ] && [ $$timing = 0 ]

check: lint typecheck
	$(BIN)/pytest tests/unit -n auto -m "not timing" -q

clean:
	rm -rf $(VENV) runs .site .mypy_cache .ruff_cache .pytest_cache $(LANE)
