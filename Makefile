# Developer and CI entry points. Needs only python3 (3.11) with venv and pip,
# and network access to PyPI for the first `make venv`.

PYTHON ?= python3
VENV := .venv
VPY := $(VENV)/bin/python
STAMP := $(VENV)/.stamp
PKG_STAMP := $(VENV)/.stamp-packages
PIP := $(VPY) -m pip
PIP_FLAGS ?= -q --disable-pip-version-check
# -n auto --maxprocesses 4: one worker per core, at most 4 (each worker claims its own DDS
# domain in tests/conftest.py); worksteal keeps both cores busy to the end, when only the
# slow multi-process tests are left. -rfEs: the short summary at the end names every failed
# test (CI shows only part of a long log). `make test PYTEST_ARGS=-q` runs it in one process.
# The realtime tests (marker realtime: a realtime graph alone on the machine) run after
# the others, in one process: under xdist each waited for the other worker's test to end
# while that worker then waited for it (tests/conftest.py's lock; ~1 minute of a run).
# PYTEST_ARGS given (command line, environment): one pytest of exactly those, the lock
# keeping the realtime tests alone.
PYTEST_ARGS ?= -q -rfEs -p no:cacheprovider --durations=25 -n auto --maxprocesses 4 --dist worksteal
PYTEST_RT_ARGS ?= -q -rfEs -p no:cacheprovider --durations=10
RT_TEST_FILES = $(shell grep -rl --include='test_*.py' realtime_loop_alone tests)

# The ament_python packages, installed editable (their console scripts land in
# $(VENV)/bin). Re-installed when a package's setup.py/setup.cfg changes (new
# entry point), a package is added, or files are added to or removed from a
# package's python dir (an editable install made before its __init__.py
# existed maps the package as a namespace package).
PKG_DIRS := $(sort $(patsubst %/setup.py,%,$(wildcard src/pkm_*/setup.py)))
PKG_META := $(wildcard src/pkm_*/setup.py src/pkm_*/setup.cfg) \
	$(foreach d,$(PKG_DIRS),$(wildcard $(d)/$(notdir $(d))))
BENCHES := $(filter-out benchmarks/hoststat.py,$(sort $(wildcard benchmarks/*.py)))

.PHONY: all venv test lint demo bench golden clean

all: test

venv: $(STAMP) $(PKG_STAMP)

# Third-party requirements: only when requirements.txt is newer than the stamp.
$(STAMP): requirements.txt
	@test -x $(VPY) || { echo "creating $(VENV) with $(PYTHON)"; $(PYTHON) -m venv $(VENV); }
	$(PIP) install $(PIP_FLAGS) --upgrade pip
	$(PIP) install $(PIP_FLAGS) -r requirements.txt
	@touch $(STAMP)

# The project's own packages (a few seconds). setuptools warns at length that
# a flat-layout editable install may be shadowed by same-named folders in the
# cwd: harmless here, silenced.
# The old ones are uninstalled first: a package that gave a console script to a new
# one (pkm_bringup's pkm-report went to pkm_runs) removed it when pip replaced it.
$(PKG_STAMP): $(STAMP) $(PKG_META)
	-@$(PIP) uninstall $(PIP_FLAGS) -y $(notdir $(PKG_DIRS)) 2>/dev/null
	PYTHONWARNINGS='ignore:Editable installation' \
		$(PIP) install $(PIP_FLAGS) --no-deps --no-build-isolation $(addprefix -e ,$(PKG_DIRS))
	@touch $(PKG_STAMP)

test: venv
	@command -v chromium >/dev/null || command -v chromium-browser >/dev/null || \
		echo "make test: chromium not found: the operator panel's browser test is skipped (apt-get install chromium)"
	$(VENV)/bin/lint-imports --no-cache
ifeq ($(origin PYTEST_ARGS),file)
	$(VPY) -m pytest -m "not realtime" $(PYTEST_ARGS)
	$(if $(RT_TEST_FILES),$(VPY) -m pytest -m realtime $(PYTEST_RT_ARGS) $(RT_TEST_FILES))
else
	$(VPY) -m pytest $(PYTEST_ARGS)
endif

# The packages' layer order and the pure core without rclpy (.importlinter); also the
# first step of `make test`.
lint: venv
	$(VENV)/bin/lint-imports --no-cache

# The default scenario (config/scenarios/archi_demo.yaml): ARCHI test motion under a
# cutting load, Gough metrology, sensor-space control, inf-norm distribution, recorded
# to runs/<date>-<time>_archi_demo/ (bag, report, plots). SCENARIO=<name|file> runs another.
SCENARIO ?= archi_demo
demo: venv
	$(VENV)/bin/pkm-run $(SCENARIO)

bench: venv
	@set -e; for f in $(BENCHES); do echo "== $$f"; $(VPY) $$f; done

# Every lockstep scenario and pkm-analyze against tests/golden/golden.json (~2 min):
# commands and true poses bit-identical, metrics to 9 digits, replay exact. The
# restructuring (issue 41) runs it after each step; `tools/golden.py record` after an
# intended change of behaviour.
golden: venv
	$(VPY) tools/golden.py compare

# Build artefacts only: keeps $(VENV), the hypothesis database and runs/.
clean:
	rm -rf build install log .pytest_cache
	find . -path ./$(VENV) -prune -o \( -name __pycache__ -o -name '*.egg-info' \) -type d -print0 \
		| xargs -0 rm -rf
