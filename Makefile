# Penumbra: two commands do everything on a fresh machine.
#   make demo   - set up .venv (and the Debian libraries bpy needs), render the sample scene
#   make test   - set up the three venvs below, run the test matrix
#
# .venv      the default development Blender: bpy 5.2.3 (the 5.2 LTS), Python 3.13, numpy 2
# .venv-5.0  bpy 5.0.1, Python 3.11, numpy 1.26
# .venv-5.3  bpy 5.3.0, Python 3.13, numpy 2
# Python 3.13 / 3.11 are found by scripts/find_python.sh (PATH, then pyenv).
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
VENV_DEPS := pyproject.toml scripts/setup_system.sh scripts/find_python.sh scripts/make_venv.sh

.PHONY: demo test bench setup clean samples wheels extension kernel-plan
.DEFAULT_GOAL := demo

setup: $(STAMP)

$(STAMP): $(VENV_DEPS)
	bash scripts/setup_system.sh
	bash scripts/make_venv.sh $(VENV) 3.13 blender52

.venv-5.0/.installed: $(VENV_DEPS)
	bash scripts/setup_system.sh
	bash scripts/make_venv.sh .venv-5.0 3.11 blender50

.venv-5.3/.installed: $(VENV_DEPS)
	bash scripts/setup_system.sh
	bash scripts/make_venv.sh .venv-5.3 3.13 blender53

demo: $(STAMP)
	$(VENV)/bin/penumbra render sample_blends/sphere_plane.blend --out demo_out --methods all --samples 64
	@echo "passes written to demo_out/"

# Core tests once (on .venv), every test that touches bpy on each Blender
# (scripts/test_matrix.py checks that every collected test ran).
test: $(STAMP) .venv-5.0/.installed .venv-5.3/.installed
	$(PY) scripts/test_matrix.py --core $(VENV) --bpy $(VENV) .venv-5.0 .venv-5.3

bench: $(STAMP)
	$(VENV)/bin/penumbra bench --out bench/results
	$(PY) -m penumbra.bench.readme_tables

samples: $(STAMP)
	$(PY) sample_blends/make_samples.py

# core/kernel_plan.json: what a cold frame compiles, in order, for the helper
# processes of core/compile_ahead.py (re-record after changing a kernel's
# signature; tests/test_compile_ahead.py fails when it is stale)
kernel-plan: $(STAMP)
	$(PY) scripts/record_kernel_plan.py --jobs 2

# The Blender extension: PyPI wheels for every platform in blender_manifest.toml
# into ./wheels/, then one zip per platform into dist/ (scripts/build_extension.py).
wheels: $(STAMP)
	$(PY) scripts/build_extension.py wheels

extension: $(STAMP)
	$(PY) scripts/build_extension.py build --out dist

clean:
	rm -rf $(VENV) .venv-5.0 .venv-5.3 demo_out .pytest_cache
