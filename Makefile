# Two entry points for a fresh machine; each creates .venv and installs what it needs.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: run test bench venv clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

## run: the main job on the bench simulator (the demo mission; the planner bench is `bench`).
## A previous demo run is kept as runs/bench-demo.prev (capm-field itself never overwrites a log).
run: $(STAMP)
	@if [ -e runs/bench-demo ]; then rm -rf runs/bench-demo.prev && mv runs/bench-demo runs/bench-demo.prev \
	  && echo "previous demo run moved to runs/bench-demo.prev"; fi
	$(BIN)/capm-field run mission/examples/bench_demo.yaml --out runs/bench-demo

## bench: the paper's Table I
bench: $(STAMP)
	$(BIN)/capm-field bench --trials 1000

## test: the default test suite in TEST_JOBS processes (pytest-xdist; slow suites: make test PYTEST_ARGS='-m slow',
## one process: make test TEST_JOBS=0)
TEST_JOBS ?= 2
test: $(STAMP)
	$(BIN)/python -m pytest -n $(TEST_JOBS) $(PYTEST_ARGS)

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
