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
	$(PY) -m ruff format --check .
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

# The bpy-free tests once more under numpy 2 (Blender 5.1+ ships numpy 2 with Python 3.13),
# in a second environment without bpy; plus ruff's numpy-2 rule on core and addon.
NP2_VENV := .venv-np2
NP2_STAMP := $(NP2_VENV)/.installed
# Python 3.13 where there is one (pyenv's shim or its install), else $(PYTHON).
NP2_PYTHON ?= $(firstword $(foreach p,python3.13 $(wildcard $(HOME)/.pyenv/versions/3.13*/bin/python3.13) $(PYTHON),$(shell $(p) -c 'print("$(p)")' 2>/dev/null)))
.PHONY: test-numpy2
$(NP2_STAMP): requirements-numpy2.txt
	@test -x $(NP2_VENV)/bin/python || $(NP2_PYTHON) -m venv $(NP2_VENV)
	$(NP2_VENV)/bin/python -m pip install --quiet -r requirements-numpy2.txt
	@touch $(NP2_STAMP)

test-numpy2: $(NP2_STAMP)
	$(NP2_VENV)/bin/python -m ruff check --select NPY201 core addon
	$(NP2_VENV)/bin/python -c 'import numpy, sys; print("numpy", numpy.__version__, "python", sys.version.split()[0]); sys.exit(int(numpy.__version__.split(".")[0]) < 2)'
	$(NP2_VENV)/bin/python -m pytest -p no:cacheprovider -m "not blender" --ignore=tests/addon

# The add-on suite against Blender 4.2 LTS: the bpy 4.2.x module (Python 3.11, numpy 1.26).
BL42_VENV := .venv-bl42
BL42_STAMP := $(BL42_VENV)/.installed
.PHONY: test-blender42
$(BL42_STAMP): requirements-blender42.txt
	@test -x $(BL42_VENV)/bin/python || $(PYTHON) -m venv $(BL42_VENV)
	$(BL42_VENV)/bin/python -m pip install --quiet -r requirements-blender42.txt
	@touch $(BL42_STAMP)

test-blender42: $(BL42_STAMP)
	$(BL42_VENV)/bin/python -c 'import bpy, sys; print("bpy", bpy.app.version_string); sys.exit(bpy.app.version[:2] != (4, 2))'
	$(BL42_VENV)/bin/python -m pytest -p no:cacheprovider -m blender tests/addon
