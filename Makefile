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

# The suite in two passes, all always run (any failing fails the target). First every
# test not marked `timing`, in three pytest runs at once:
# - the tests with real processes, sessions or clocks on REAL_WORKERS parallel workers;
# - beside them, those marked `testbed` one after another in a lane of their own (one
#   network testbed runs on a host at a time; their lab processes run ahead of the rest),
#   with a few long ones marked `lane` that fill the lane while the workers run the others;
# - the tests of pure computation (marked `computation` by tests/conftest.py) on
#   COMPUTATION_WORKERS workers at nice 5: the real processes come first on the cores (at
#   the same priority beside them a follower's 100 Hz steps came up to 167 ms apart on a
#   2-core machine); at nice 10 some took 5 times as long as at nice 0.
# The lane's output and the computation's follow the workers'. The project's modules are
# compiled first, once: the agents, routers and links the tests start import them from
# bytecode even where PYTHONDONTWRITEBYTECODE is set (0.59 s of CPU per agent's imports
# from source, 0.41 s from bytecode). Then the `timing` tests one at a time (real-time
# bounds on a closed loop, an abort's latency, a start's spread: claims about processes
# that have the cores to themselves). Sync accuracy is judged against the bound each
# estimate states in the same run, so it holds on shared cores.
WORKERS ?= 4
REAL_WORKERS ?= 4
COMPUTATION_WORKERS ?= 2
LANE := .testbed-lane

test: lint typecheck
	rm -rf $(LANE) && mkdir -p $(LANE)
	$(BIN)/python -m compileall -q federation agents schemas > /dev/null
	$(BIN)/pytest tests -m "(testbed or lane) and not timing" -p no:cacheprovider \
		--basetemp=$(LANE)/tmp > $(LANE)/log 2>&1 & lane=$$!; \
	nice -n 5 $(BIN)/pytest tests/unit -n $(COMPUTATION_WORKERS) --dist worksteal \
		-m "computation and not timing" -p no:cacheprovider --basetemp=$(LANE)/computation \
		> $(LANE)/computation.log 2>&1 & computation=$$!; \
	$(BIN)/pytest tests -n $(REAL_WORKERS) --dist worksteal \
		-m "not timing and not testbed and not lane and not computation"; \
	real=$$?; wait $$computation; pure=$$?; wait $$lane; testbed=$$?; \
	echo "--- the testbed lane (pytest -m '(testbed or lane) and not timing') ---"; cat $(LANE)/log; \
	echo "--- pure computation (nice -n 5 pytest -m 'computation and not timing') ---"; \
	cat $(LANE)/computation.log; \
	$(BIN)/pytest tests -m timing; timing=$$?; \
	[ $$real = 0 ] && [ $$pure = 0 ] && [ $$testbed = 0 ] && [ $$timing = 0 ]

check: lint typecheck
	$(BIN)/pytest tests/unit -n $(WORKERS) --dist worksteal -m "not timing" -q

clean:
	rm -rf $(VENV) runs .site .mypy_cache .ruff_cache .pytest_cache $(LANE)
