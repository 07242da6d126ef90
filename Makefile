# One-command set-up on a fresh Debian machine (Python 3.11, gcc, apt):
#   make demo   set up .venv and convert a bundled sample plant
#   make test   set up .venv and run the test suite
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DEMO_IN  ?= samples/plants/rubber_tree.ply
DEMO_OUT ?= out/demo
# the sample plants are generated here, not kept in git (deterministic: same bytes every time)
SAMPLES  := samples/plants/.generated

.PHONY: demo test setup samples bench clean dcc-check

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/setup_system.sh
	./scripts/setup_system.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev,formats,dask]'
	touch $(STAMP)

$(SAMPLES): $(STAMP) samples/generate.py samples/leaves.py
	$(PY) -m samples.generate --committed --out samples/plants -q
	touch $(SAMPLES)

samples: $(SAMPLES)

demo: $(STAMP) $(SAMPLES)
	$(PY) -m leaffit_usd.demo $(DEMO_IN) $(DEMO_OUT)

test: $(STAMP) $(SAMPLES)
	$(PY) -m pytest -q -p no:cacheprovider

bench: $(STAMP) $(SAMPLES)
	$(PY) benchmarks/run_all.py

clean:
	rm -rf $(VENV) out build *.egg-info

# Optional (not part of `make test`): import a LeafFit stage into Blender 4.2 (bpy module, headless,
# separate venv in build/, ~0.5 GB) and check instances, material slots and textures.
# make dcc-check [DCC_FILE=out/plant.usda]   (default: the usd tests' synthetic plant)
dcc-check: $(STAMP)
	test -x build/dcc-venv/bin/python || { $(PYTHON) -m venv build/dcc-venv && build/dcc-venv/bin/pip install -q 'bpy==4.2.0' 'numpy<2'; }
	set -e; stage=$$($(PY) tests/usd/dcc/make_stage.py $(DCC_FILE)); build/dcc-venv/bin/python tests/usd/dcc/blender_check.py $$stage
