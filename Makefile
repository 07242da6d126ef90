# One-command set-up on a fresh Debian machine (Python 3.11, gcc, apt):
#   make demo   set up .venv and convert a bundled sample plant
#   make test   set up .venv and run the test suite
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
# the Khronos glTF validator (npm), used by the glTF export tests
GLTF_VALIDATOR := build/gltf-validator/node_modules/gltf-validator/package.json
GLTF_VALIDATOR_VERSION := 2.0.0-dev.3.10
DEMO_IN  ?= samples/plants/rubber_tree.ply
DEMO_OUT ?= out/demo
# the sample plants are generated here, not kept in git (deterministic: same bytes every time)
SAMPLES  := samples/plants/.generated

.PHONY: demo test setup samples bench clean dcc-check

setup: $(STAMP) $(GLTF_VALIDATOR)

$(STAMP): pyproject.toml scripts/setup_system.sh
	./scripts/setup_system.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev,formats,dask,scans]'
	touch $(STAMP)

$(SAMPLES): $(STAMP) samples/generate.py samples/leaves.py
	$(PY) -m samples.generate --committed --out samples/plants -q
	touch $(SAMPLES)

samples: $(SAMPLES)

demo: $(STAMP) $(SAMPLES)
	$(PY) -m leaffit_usd.demo $(DEMO_IN) $(DEMO_OUT)

$(GLTF_VALIDATOR): scripts/setup_system.sh
	npm install --prefix build/gltf-validator --no-audit --no-fund --silent gltf-validator@$(GLTF_VALIDATOR_VERSION)
	touch $(GLTF_VALIDATOR)

test: $(STAMP) $(SAMPLES) $(GLTF_VALIDATOR)
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
