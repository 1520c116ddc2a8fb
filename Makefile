# The two set-up commands of the README (make demo, make test) and the benchmarks.
# Each target creates .venv when it is missing and installs the project with its test extras.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
SECONDS ?= 30

.PHONY: demo test bench clean bytecode

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

# Qt's X11 platform plugin needs these system libraries; a display with any of them missing gets
# them installed (root), or the demo renders the operator screen headless and says why.
QT_XCB_LIBS := libxcb-cursor0 libxcb-icccm4 libxcb-keysyms1 libxcb-image0 libxcb-render-util0 libxcb-randr0 \
               libxcb-shape0 libxcb-xinerama0 libxcb-xkb1 libxkbcommon-x11-0 libegl1 libfontconfig1 libdbus-1-3

# Every controller process imports the project's modules afresh. Where PYTHONDONTWRITEBYTECODE is
# set (the build machines' environment sets it) nothing is cached and each process compiles them
# from source again: about 0.3 s of each process's start, paid hundreds of times by the tests.
# compileall writes the cache once (only what changed); the interpreter reads it either way.
bytecode: $(STAMP)
	@$(PY) -m compileall -q -j 0 cnc hmi plc_link gcode >/dev/null

demo: $(STAMP) bytecode
	@if [ -n "$$DISPLAY" ] && ldd "$$($(PY) -c 'import PySide6, pathlib; print(pathlib.Path(PySide6.__file__).parent / "Qt/plugins/platforms/libqxcb.so")')" | grep -q "not found"; then \
	  if [ "$$(id -u)" = 0 ]; then echo "make demo: installing Qt's X11 libraries"; \
	    (apt-get install -y -qq $(QT_XCB_LIBS) || (apt-get update -qq && apt-get install -y -qq $(QT_XCB_LIBS))) >/dev/null 2>&1 || true; \
	  else echo "make demo: Qt's X11 libraries are missing (sudo apt-get install $(QT_XCB_LIBS))"; fi; fi
	$(VENV)/bin/waterjet demo

# Two lanes at once (tests/lanes.py): the modules marked `computes` (pure computation) in a second
# pytest process at idle priority (every thread of it: started under chrt --idle, BLAS without
# worker threads), using the CPU the main lane leaves idle while it waits on its controllers;
# their report follows the main lane's; the main lane's tests marked `alone` run last, once the
# computes lane has ended. Either failing fails the target.
# And /dev/shm left as the run found it (the tests check their own leftovers; this, after the
# test processes have ended, also what Python's resource tracker should have removed)
test: $(STAMP) bytecode
	@ls -A /dev/shm 2>/dev/null | sort > .shm-before || true
	@base=$$(mktemp -d); idle=$$(command -v chrt >/dev/null && echo chrt --idle 0); \
	  WATERJET_TEST_LANE=computes OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 \
	    $$idle $(PY) -m pytest -m computes -p no:cacheprovider --durations=10 --basetemp=$$base/tmp \
	    > $$base/computes.log 2>&1 & lane=$$!; \
	  trap 'kill $$lane 2>/dev/null; rm -rf $$base' INT TERM; \
	  echo "$(PY) -m pytest -m 'not computes'   (and the computes lane beside it, reported below)"; \
	  WATERJET_COMPUTES_LANE_PID=$$lane $(PY) -m pytest -m "not computes" --durations=25; main=$$?; \
	  wait $$lane; computes=$$?; \
	  echo; echo "==== the computes lane: $(PY) -m pytest -m computes (idle priority, beside the above)"; \
	  cat $$base/computes.log; rm -rf $$base; \
	  if [ $$main != 0 ] || [ $$computes != 0 ]; then rm -f .shm-before; exit 1; fi
	@ls -A /dev/shm 2>/dev/null | sort | comm -13 .shm-before - > .shm-left || true; \
	  if [ -s .shm-left ]; then echo "make test: left in /dev/shm:"; cat .shm-left; rm -f .shm-before .shm-left; exit 1; fi; \
	  rm -f .shm-before .shm-left

bench: $(STAMP) bytecode
	@command -v cyclictest >/dev/null || { [ "$$(id -u)" = 0 ] && (apt-get update -qq && apt-get install -y -qq rt-tests) >/dev/null 2>&1; } || true
	$(PY) bench/servo_timing.py --seconds $(SECONDS) --feeder all
	$(PY) bench/tracking.py
	$(PY) bench/planner_throughput.py
	$(PY) bench/linuxcnc_compare.py
	$(PY) bench/gcode_speed.py
	QT_QPA_PLATFORM=offscreen $(PY) bench/hmi_contour.py
	QT_QPA_PLATFORM=offscreen $(PY) bench/hmi_window.py
	QT_QPA_PLATFORM=offscreen $(PY) bench/load.py
	$(PY) bench/faults.py
	$(PY) bench/soak.py --minutes 2

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
	find cnc hmi plc_link gcode tests bench -name __pycache__ -type d -prune -exec rm -rf {} +
