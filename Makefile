# The two set-up commands of the README (make demo, make test) and the benchmarks.
# Each target creates .venv when it is missing and installs the project with its test extras.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
SECONDS ?= 30

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/waterjet demo

test: $(STAMP)
	$(PY) -m pytest

bench: $(STAMP)
	@command -v cyclictest >/dev/null || { [ "$$(id -u)" = 0 ] && (apt-get update -qq && apt-get install -y -qq rt-tests) >/dev/null 2>&1; } || true
	$(PY) bench/servo_timing.py --seconds $(SECONDS)
	$(PY) bench/tracking.py
	$(PY) bench/planner_throughput.py
	$(PY) bench/linuxcnc_compare.py
	$(PY) bench/gcode_speed.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
