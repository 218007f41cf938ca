# Penumbra: two commands do everything on a fresh machine.
#   make demo   - set up .venv (and the Debian libraries bpy needs), render the sample scene
#   make test   - set up .venv, run the test suite
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test bench setup clean samples wheels extension
.DEFAULT_GOAL := demo

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/setup_system.sh
	bash scripts/setup_system.sh
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON)"; exit 2; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[blender,dev,farm,farm-dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/penumbra render sample_blends/sphere_plane.blend --out demo_out --methods all --samples 64
	@echo "passes written to demo_out/"

test: $(STAMP)
	$(PY) -m pytest -q tests

bench: $(STAMP)
	$(VENV)/bin/penumbra bench --out bench/results

samples: $(STAMP)
	$(PY) sample_blends/make_samples.py

# The Blender extension: PyPI wheels for every platform in blender_manifest.toml
# into ./wheels/, then one zip per platform into dist/ (scripts/build_extension.py).
wheels: $(STAMP)
	$(PY) scripts/build_extension.py wheels

extension: $(STAMP)
	$(PY) scripts/build_extension.py build --out dist

clean:
	rm -rf $(VENV) demo_out .pytest_cache
