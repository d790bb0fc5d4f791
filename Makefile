PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

# Let the suite's hundreds of processes reuse compiled bytecode (this environment sets
# PYTHONDONTWRITEBYTECODE=1, so each one compiled the project again: ~0.3 s of CPU per process).
unexport PYTHONDONTWRITEBYTECODE

.PHONY: demo test test-unit test-integration bench bench-fit clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip >/dev/null
	$(BIN)/pip install -e '.[dev,camera]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/vsfleet run scenarios/paper-triangle.toml

# the whole suite (CI: .ci/run): the unit tier on both cores, then the multi-process tests two files
# at a time (each file's tests in one worker, in order); test-unit: every test that starts no process.
# The unit tier runs --dist worksteal: plain load scheduling hands a worker one chunk of consecutive
# tests (all of tests/test_closed_loop.py's offline runs) that the idle worker cannot take back
test: $(STAMP)
	$(BIN)/python -m pytest -q -m "not integration" -n 2 --dist worksteal
	$(BIN)/python -m pytest -q -m integration -n 2 --dist loadfile

test-unit: $(STAMP)
	$(BIN)/python -m pytest -q -m "not integration" -n 2 --dist worksteal

test-integration: $(STAMP)
	$(BIN)/python -m pytest -q -m integration -n 2 --dist loadfile

bench-fit: $(STAMP)
	$(BIN)/python bench/fit.py

# every benchmark -> docs/benchmarks.md + docs/bench/*.png (20-40 min; BENCH_ARGS=--quick for a short run)
bench: $(STAMP)
	$(BIN)/python -m bench.run_all $(BENCH_ARGS)

clean:
	rm -rf $(VENV) runs .pytest_cache .hypothesis
