# linemap: the two commands a new user runs are `make demo` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
NUMBA_STAMP := $(VENV)/.numba-cache-stamp

.PHONY: demo demo-map map test install lint typecheck pytest bench report worlds soak clean

# PORT: the server's port (make demo PORT=8080).
PORT ?= 8000
demo: install $(NUMBA_STAMP)  ## server + simulated robot + dashboard on http://127.0.0.1:$(PORT) until Ctrl-C
	$(BIN)/linemap demo --port $(PORT)

# The demo left running, pictured: after DEMO_S seconds of patrol its map (as the server holds it) over the
# true walls, then it stops. DEMO_WORLD: room (the paper's room) or a scenario-suite kind.
DEMO_S ?= 600
DEMO_WORLD ?= room
demo-map: install $(NUMBA_STAMP)  ## the demo for DEMO_S s (600), then its map as demo-map.png
	$(BIN)/linemap demo --dir .demo-map --port $(PORT) --world $(DEMO_WORLD) --for-s $(DEMO_S) --png demo-map.png

map: install $(NUMBA_STAMP)  ## offline: map the simulated world, draw it, print the accuracy
	$(BIN)/linemap map sim --out map.geojson --svg map.svg --png map.png --trajectory-out trajectory.csv

test: install lint typecheck pytest  ## ruff, mypy and pytest in a fresh or updated virtual environment

install: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,bench]'
	touch $(STAMP)

lint: install
	$(BIN)/ruff check .

typecheck: install
	$(BIN)/mypy

# numba's on-disk cache only watches the file that defines a jitted function, not the jitted helpers it
# calls from other modules: drop the cache whenever any source under shared/ changed.
$(NUMBA_STAMP): $(shell find shared -name '*.py' 2>/dev/null) | $(STAMP)
	find shared -name '*.nbi' -delete -o -name '*.nbc' -delete
	touch $@

# pytest exits 5 when it collected no test: that must fail, never pass silently. WORKERS: pytest-xdist
# processes, each taking a whole test file at a time (module fixtures stay in one process); 0 runs serially.
WORKERS ?= 2
pytest: install $(NUMBA_STAMP)
	$(BIN)/python -m pytest -q -p no:cacheprovider -m "not soak" -n $(WORKERS) --dist loadfile; rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "pytest collected no tests: failing" >&2; exit 1; fi; exit $$rc

soak: install $(NUMBA_STAMP)  ## the whole reliability suite and every long run make test leaves out (see tests/reliability/soakrun.py)
	$(BIN)/python -m tests.reliability.soakrun

report: install $(NUMBA_STAMP)  ## regenerate docs/report/ (the paper's results against EKF-SLAM; ~15 min)
	$(BIN)/linemap report --out docs/report

worlds: install $(NUMBA_STAMP)  ## regenerate docs/report/worlds.md, the scenario suite the README cites (~4 min)
	$(BIN)/linemap report --worlds-only --out docs/report

bench: install $(NUMBA_STAMP)  ## kernel benchmark with JSON output
	$(BIN)/linemap bench kernels --json bench-kernels.json

clean:
	rm -rf $(VENV) .mypy_cache .ruff_cache .demo .demo-map demo-map.png test-artifacts bench-kernels.json map.geojson map.svg map.png trajectory.csv
	find shared -name '*.nbi' -delete -o -name '*.nbc' -delete
