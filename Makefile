# Everything a fresh machine needs: `make demo` and `make test` create .venv themselves.
PYTHON ?= python3
VENV ?= .venv
# The CPU build is enough for the demo and the tests; override for CUDA, e.g. TORCH=torch.
TORCH ?= torch==2.13.0
PY := $(VENV)/bin/python
# Test processes (pytest-xdist): the suite's subprocess and training tests use a core each.
TEST_JOBS ?= 2

.PHONY: demo test test-all lint format venv clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q "$(TORCH)"
	$(PY) -m pip install -q -e ".[dev,smpl]"
	touch $@

venv: $(VENV)/.installed

# The demo fine-tunes on real takes where a folder of them is at hand (DEMO_DATA=your/folder; in
# the project's own checkouts the Bandai Namco sample beside it), else on the embedded synthetic motion.
DEMO_DATA ?= $(wildcard ../shared/data/bandai-namco)

demo: $(VENV)/.installed
	$(PY) -m mocapfix demo $(if $(DEMO_DATA),--data $(DEMO_DATA))

# The everyday suite: lint and format check (ruff, settings in pyproject.toml), then the tests;
# tests marked slow (minutes of CPU training) run with `make test-all`. `make format` fixes both.
test: $(VENV)/.installed lint
	$(PY) -m pytest -q -ra -m "not slow" -n $(TEST_JOBS) --durations=15

lint: $(VENV)/.installed
	$(VENV)/bin/ruff check mocapfix tests bench scripts
	$(VENV)/bin/ruff format --check mocapfix tests bench scripts

format: $(VENV)/.installed
	$(VENV)/bin/ruff check --fix mocapfix tests bench scripts
	$(VENV)/bin/ruff format mocapfix tests bench scripts

test-all: $(VENV)/.installed
	$(PY) -m pytest -q -ra -n $(TEST_JOBS)

clean:
	rm -rf $(VENV) .cache
