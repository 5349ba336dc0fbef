# make demo : set up .venv, encode and decode the built-in procedural scene
# make test : set up .venv, run the test suite
# make node-tools : @playcanvas/splat-transform (pinned in tools/node/package-lock.json) for tools/bench_real.py
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup demo test test-slow spec bench clean node-tools

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

setup: $(STAMP)

demo: setup
	$(VENV)/bin/lghcc-enc --procedural 20000 -o demo_out/demo.lghcc --force
	$(VENV)/bin/lghcc-dec demo_out/demo.lghcc -o demo_out/decoded

test: setup
	$(PY) -m pytest

test-slow: setup
	$(PY) -m pytest -m slow

# npm ci: exactly the locked versions; --ignore-scripts: the one install script (webgpu's) only
# clears a macOS quarantine flag. splat-transform 3.7.0 declares node >= 22 but runs on node 20.
NODE_STAMP := tools/node/node_modules/.package-lock.json

$(NODE_STAMP): tools/node/package.json tools/node/package-lock.json
	@command -v npm >/dev/null || { echo "make node-tools: npm not found: install Node.js (20 or later) with npm"; exit 1; }
	cd tools/node && npm ci --ignore-scripts --no-audit --no-fund --loglevel=error
	touch $(NODE_STAMP)

node-tools: $(NODE_STAMP)

spec: setup
	$(PY) tools/gen_spec_tables.py

clean:
	rm -rf demo_out build *.egg-info
