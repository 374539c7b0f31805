# thinkfast: every target installs what it needs into .venv first.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
CONFIG ?= trees/irb1600_default.toml
TREE   ?= trees/irb1600_default.h5

.PHONY: install lock lock-check test test-quarantine demo lint bench clean

$(TREE): $(STAMP) $(CONFIG)
	$(VENV)/bin/thinkfast-compile tree $(CONFIG) -o $(TREE) --if-changed

# Python's bytecode caches (the gitignored __pycache__ directories) are written even where the
# environment sets PYTHONDONTWRITEBYTECODE: the tests and the demo start the package's programs
# hundreds of times, and without the caches every start compiles the package again (0.4 s of
# CPU per daemon start, pytest's collection 11.6 s instead of 5.0 s: docs/BENCHMARKS.md).
unexport PYTHONDONTWRITEBYTECODE

# numba compiles the decision's compiled kernels (thinkfast/*/*_jit.py, chosen per process by
# THINKFAST_KERNELS: thinkfast/robot/kernels.py) once into its disk cache, next to the sources
# (about 6 s), before the daemon, the demo or the tests need them; again only when a kernel's
# source changes (the stamp). The tests' own processes run the numpy kernels (tests/conftest.py);
# the tests of the compiled ones then only load the cache, no two workers compiling the same
# kernel (numba writes its cache files atomically anyway).
KERNELS := $(VENV)/.kernels-stamp
$(KERNELS): $(STAMP) $(wildcard thinkfast/*/*_jit.py)
	THINKFAST_KERNELS=compiled $(PY) -c 'from thinkfast.decide import pair_jit as p, tree_jit as t; p.warm_up(); t.warm_up()'
	touch $(KERNELS)

# The environment is requirements.lock: every package of every extra at one version, with its
# hashes (uv pip compile --universal from pyproject.toml's ranges, which stay for those who
# install the package into an environment of their own). uv, at one version, into the venv
# installs the lock and then the package alone (--no-deps), downloading in parallel: 3 min
# against 16 min for pip on a loaded host (docs/BENCHMARKS.md, "The test suite"). Plain pip,
# the same two steps, when uv cannot be had or fails.
UV_VERSION := 0.13.9
UV   := $(VENV)/bin/uv
LOCK := requirements.lock

# Before anything is installed: whether the lock was compiled from pyproject.toml's dependencies
# as they are (a digest in its header, every direct requirement pinned); one line and a failure
# when not. Stdlib only, offline, run (order-only) before every install and so every `make test`.
lock-check:
	@$(PYTHON) .ci/lock_check.py
$(LOCK):  # only when it is missing: the check says so
	@$(PYTHON) .ci/lock_check.py

$(STAMP): pyproject.toml $(LOCK) | lock-check
	$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "thinkfast needs Python >= 3.11"'
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q uv==$(UV_VERSION) \
	  && $(UV) pip install -q --native-tls --compile-bytecode --python $(PY) --require-hashes -r $(LOCK) \
	  && $(UV) pip install -q --native-tls --compile-bytecode --python $(PY) --no-deps -e . \
	  || { $(PY) -m pip install -q --upgrade pip && $(PY) -m pip install -q --require-hashes -r $(LOCK) \
	       && $(PY) -m pip install -q --no-deps -e .; }
	touch $(STAMP)

# requirements.lock again from pyproject.toml, after a dependency there changed: uv keeps the
# lock's pins that still fit; LOCK_FLAGS=--upgrade moves every package to its newest version,
# LOCK_FLAGS='--upgrade-package numpy' one. Then the header with the digest (.ci/lock_check.py).
LOCK_FLAGS ?=
lock:
	$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "thinkfast needs Python >= 3.11"'
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q uv==$(UV_VERSION)
	$(UV) pip compile -q --native-tls pyproject.toml --all-extras --universal --generate-hashes \
	    --python-version 3.11 --no-header $(LOCK_FLAGS) -o $(LOCK)
	$(PYTHON) .ci/lock_check.py --stamp

install: $(STAMP) $(KERNELS)

# Two steps: tests on simulated or no time in parallel (one worker per core, a module's tests
# on one worker, the longest modules first: tests/conftest.py LONG_MODULES), then the ones whose
# outcome depends on the wall clock (marker `realtime`) one at a time, so that no other test
# loads the machine under them.
JOBS ?= auto
# The real-time step collects only the files that name the marker (a superset of those with a
# realtime test): collecting all of them cost twice the CPU for the same tests.
RT_FILES = $(shell grep -lw realtime tests/test_*.py)

test: $(STAMP) $(KERNELS)
	$(PY) -m pytest -q -m "not realtime and not quarantine" -n $(JOBS) --dist loadscope \
	    --no-loadscope-reorder --durations=10
	$(PY) -m pytest -q -m "realtime and not quarantine" -p no:xdist --durations=10 \
	    $(RT_FILES)

test-quarantine: $(STAMP)
	$(PY) -m pytest -q -m quarantine -p no:xdist

THROWS ?= 5

demo: $(STAMP) $(KERNELS)
	$(VENV)/bin/thinkfast-compile goals $(CONFIG)
	$(VENV)/bin/thinkfast-compile tree $(CONFIG) -o $(TREE) --if-changed
	$(VENV)/bin/thinkfast-sim run --tree $(TREE) --throws $(THROWS) --planner tree
	$(VENV)/bin/thinkfast-sim run --tree $(TREE) --throws $(THROWS) --planner naive

lint: $(STAMP)
	$(VENV)/bin/ruff check thinkfast tests bench
	$(VENV)/bin/ruff format --check thinkfast tests bench
	$(VENV)/bin/lint-imports
	@# every robot folder's controller kit is what robot.toml gives (thinkfast-compile kit)
	@for t in robots/*/robot.toml; do [ ! -d "$${t%/robot.toml}/controller" ] || \
	  $(VENV)/bin/thinkfast-compile kit "$$t" --check || exit 1; done

bench: $(STAMP) $(KERNELS) $(TREE)
	$(PY) bench/compile.py
	$(PY) bench/decision.py --tree $(TREE)
	$(VENV)/bin/thinkfast-sim bench --tree $(TREE) --throws 500 --seed 1
	$(PY) bench/egm_latency.py --n 20000
	$(PY) bench/detect.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
