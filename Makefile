PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

# Let the suite's hundreds of processes reuse compiled bytecode (this environment sets
# PYTHONDONTWRITEBYTECODE=1, so each one compiled the project again: ~0.3 s of CPU per process).
unexport PYTHONDONTWRITEBYTECODE

.PHONY: demo test test-unit test-fleet test-integration bench bench-fit clean core test-cross test-sanitize test-noalloc

CORE_SRC := $(wildcard vsfleet/_core/*.c vsfleet/_core/*.h) setup.py

$(STAMP): pyproject.toml setup.py
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip >/dev/null
	$(BIN)/pip install -e '.[dev,camera]'
	touch $(STAMP)

# the compiled core (vsfleet/_core -> vsfleet/_core*.so beside the sources), rebuilt when a source
# changes; flock: several shells may build at once
CORE_SO := vsfleet/.core-built
$(CORE_SO): $(STAMP) $(CORE_SRC)
	flock /tmp/vsfleet-core.lock $(BIN)/python setup.py -q build_ext --inplace
	touch $(CORE_SO)

core: $(CORE_SO)

demo: $(STAMP) $(CORE_SO)
	$(BIN)/vsfleet run scenarios/paper-triangle.toml

# the whole suite (CI: .ci/run): the unit tier and the fleet tier (closed-loop runs of a simulated fleet in
# process: tests/conftest.py's FLEET_MODULES) on both cores, then the multi-process tests two files at a time
# (each file's tests in one worker, in order). test-unit: every test that starts no process and runs no fleet.
# Those tiers run --dist worksteal: plain load scheduling hands a worker one chunk of consecutive tests (all of
# tests/test_closed_loop.py's offline runs) that the idle worker cannot take back
test: $(STAMP) $(CORE_SO)
	$(BIN)/python -m pytest -q -m "not integration and not fleet" -n 2 --dist worksteal
	$(BIN)/python -m pytest -q -m fleet -n 2 --dist worksteal
	$(BIN)/python -m pytest -q -m integration -n 2 --dist loadfile

test-unit: $(STAMP) $(CORE_SO)
	$(BIN)/python -m pytest -q -m "not integration and not fleet" -n 2 --dist worksteal

test-fleet: $(STAMP) $(CORE_SO)
	$(BIN)/python -m pytest -q -m fleet -n 2 --dist worksteal

test-integration: $(STAMP) $(CORE_SO)
	$(BIN)/python -m pytest -q -m integration -n 2 --dist loadfile

# The core's golden vectors on aarch64: the core and a plain C driver cross-compiled (static, so
# qemu needs no sysroot), run under qemu-aarch64 (Debian: gcc-aarch64-linux-gnu libc6-dev-arm64-cross
# qemu-user; .ci/run installs them)
CORE_C := $(filter-out vsfleet/_core/py_%.c vsfleet/_core/module.c,$(wildcard vsfleet/_core/*.c))
# -Werror: the core and both drivers build without a warning (-Wall brings -Wsequence-point: the fuzz
# driver once wrote in[len++] = f(len), unsequenced; tests/test_core_warnings.py holds this)
# -pthread: the field's raster runs on two threads (vs_field.c raster_all)
CORE_CFLAGS := -std=c99 -O2 -ffp-contract=off -fno-fast-math -Wall -Wextra -Werror -pthread -Ivsfleet/_core
GOLDEN := tests/data/golden-core.txt
test-cross:
	mkdir -p build
	aarch64-linux-gnu-gcc $(CORE_CFLAGS) -static -o build/golden-aarch64 $(CORE_C) tests/cdriver/golden_driver.c -lm
	qemu-aarch64 build/golden-aarch64 $(GOLDEN)
	gcc $(CORE_CFLAGS) -DVS_FIELD_NO_THREADS -o build/golden-serial $(CORE_C) tests/cdriver/golden_driver.c -lm
	build/golden-serial $(GOLDEN)

# The agent's frame allocates nothing once its mission's workspace is sized (issue 29): malloc, calloc, realloc,
# posix_memalign and qsort wrapped and counted (tests/test_core_no_alloc.py runs the same)
NOALLOC_WRAP := -Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc,--wrap=posix_memalign,--wrap=qsort
test-noalloc:
	mkdir -p build
	gcc $(CORE_CFLAGS) $(NOALLOC_WRAP) -o build/noalloc $(CORE_C) tests/cdriver/noalloc_driver.c -lm
	build/noalloc

# The core under AddressSanitizer and UBSan: the golden vectors, then a fuzz of every C entry point, then the
# frames without allocation (each workspace exactly its size: ASan sees a kernel write past it), then a deferred
# field whose resolution runs out of memory at each of its allocations in turn (tests/cdriver/field_nomem_driver.c),
# then the golden vectors under ThreadSanitizer (the field's raster runs on two threads)
NOMEM_WRAP := -Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc,--wrap=posix_memalign
SAN := -fsanitize=address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer -g
test-sanitize:
	mkdir -p build
	gcc $(CORE_CFLAGS) $(SAN) -o build/golden-san $(CORE_C) tests/cdriver/golden_driver.c -lm
	ASAN_OPTIONS=detect_leaks=1 build/golden-san $(GOLDEN)
	gcc $(CORE_CFLAGS) $(SAN) -o build/fuzz-san $(CORE_C) tests/cdriver/fuzz_driver.c -lm
	ASAN_OPTIONS=detect_leaks=1 build/fuzz-san 20000
	gcc $(CORE_CFLAGS) $(SAN) $(NOALLOC_WRAP) -o build/noalloc-san $(CORE_C) tests/cdriver/noalloc_driver.c -lm
	ASAN_OPTIONS=detect_leaks=1 build/noalloc-san
	gcc $(CORE_CFLAGS) $(SAN) $(NOMEM_WRAP) -o build/field-nomem-san $(CORE_C) tests/cdriver/field_nomem_driver.c -lm
	ASAN_OPTIONS=detect_leaks=1 build/field-nomem-san
	gcc $(CORE_CFLAGS) -fsanitize=thread -g -o build/golden-tsan $(CORE_C) tests/cdriver/golden_driver.c -lm
	TSAN_OPTIONS=halt_on_error=1 build/golden-tsan $(GOLDEN)

bench-fit: $(STAMP) $(CORE_SO)
	$(BIN)/python bench/fit.py

# every benchmark -> docs/benchmarks.md + docs/bench/ + docs/img/ (20-40 min; BENCH_ARGS=--quick for a short run);
# --docs: the one place the benchmarks write into docs/ (run alone, bench/*.py write under runs/bench/)
bench: $(STAMP) $(CORE_SO)
	$(BIN)/python -m bench.run_all --docs $(BENCH_ARGS)

clean:
	rm -rf $(VENV) runs .pytest_cache .hypothesis
