# One-command set-up on a fresh Debian machine (Python 3.11, gcc, apt):
#   make demo   set up .venv and convert a bundled sample plant
#   make test   set up .venv and run the test suite
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DEMO_IN  ?= samples/plants/rubber_tree.ply
DEMO_OUT ?= out/demo

.PHONY: demo test setup bench clean dcc-check

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/setup_system.sh
	./scripts/setup_system.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m leaffit_usd.demo $(DEMO_IN) $(DEMO_OUT)

test: $(STAMP)
	$(PY) -m pytest -q -p no:cacheprovider

bench: $(STAMP)
	$(PY) benchmarks/run_all.py

clean:
	rm -rf $(VENV) out build *.egg-info
