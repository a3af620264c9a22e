# Somacap — two commands for a fresh machine: `make demo` and `make test`.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test test-core lint env clean

# Create the environment when missing (or when requirements.txt changed), reuse it otherwise.
$(STAMP): requirements.txt
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	@touch $(STAMP)

env: $(STAMP)

demo: $(STAMP)
	$(PY) -m sample_scenes.demo

test: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m pytest

test-core: $(STAMP)
	$(PY) -m pytest -m "not blender"

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

clean:
	rm -rf out build dist .pytest_cache .ruff_cache

# The installable extension zips (one per platform, scipy + OpenCV wheels bundled) in dist/.
.PHONY: extension
extension: $(STAMP)
	$(PY) -m addon.packaging
