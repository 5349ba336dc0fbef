# make demo : set up .venv, encode and decode the built-in procedural scene
# make test : set up .venv, run the fast default tier of the tests (the inner loop)
# make test-integration : the heavy integration tier (-m integration: the conformance generator's check, Node and
#   Chromium, pyright, the newcomer and wheel checks, big encodes, the tools' smoke runs); CI runs both
# make conformance-regen : make the conformance streams again from conformance/sources.yaml (a format change or a
#   stream added; IDS="c121_x ...": only those) and rewrite conformance/manifest.yaml (conformance/README.md)
# make conformance-check : the streams against conformance/manifest.yaml, then the reference decoder over them
# make check : the architecture checks (static import resolution, complexity, function length)
# make node-tools : install the pinned npm tools (tools/node: splat-transform, PlayCanvas engine, esbuild, pyright)
# make viewer-bundle : install them and build lghcc-view's JavaScript bundle
# make js-package : the npm packages lghcc-decoder, lghcc-playcanvas and lghcc-three (js/) as tarballs in dist/ (npm pack)
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup demo test test-integration test-slow check spec conformance-regen conformance-check bench clean node-tools viewer-bundle js-package fuzz-long fuzz-diff mutations js-mutations

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	# PYTHONWARNINGS: pip prints the build backend's notices even with -q (an editable install
	# of a package-dir mapping gets setuptools' "Editable installation" notice); lghcc's own
	# configuration raises no warning (tests/test_newcomer.py::test_install_is_quiet builds a wheel and checks)
	PYTHONWARNINGS=ignore $(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

setup: $(STAMP)

# -y: the demo replaces its own outputs, so that it can be run again
demo: setup
	$(VENV)/bin/lghcc-enc --procedural 20000 -o demo_out/demo.lghcc -y
	$(VENV)/bin/lghcc-dec demo_out/demo.lghcc -o demo_out/decoded -y

test: setup
	$(PY) -m pytest

test-integration: setup
	$(PY) -m pytest -m integration

test-slow: setup
	$(PY) -m pytest -m slow

# The architecture checks alone (tests/test_architecture.py; make test runs them, but for pyright's, which
# is in the integration tier): imports resolvable from the checkout (pyright, pinned in tools/node),
# complexity (ruff C901) and length of functions
check: setup node-tools
	$(PY) -m pytest -q -m 'not slow' tests/test_architecture.py

spec: setup
	$(PY) tools/gen_spec_tables.py

# The conformance streams are frozen (conformance/README.md): made again only when the format changes
# or a stream is added, never because the encoder changed
IDS ?=
conformance-regen: setup
	$(PY) -m lghcc.conformance.generate $(IDS)

conformance-check: setup
	$(PY) -m lghcc.conformance.manifest
	$(PY) -m lghcc.conformance.runner

# npm tools pinned in tools/node/package-lock.json (npm ci: exactly those versions): splat-transform
# (format interop tests, SPZ/SOG columns of the benchmarks), the PlayCanvas engine and esbuild (lghcc-view)
node-tools:
	@if command -v npm >/dev/null 2>&1; then npm ci --prefix tools/node; \
	else echo "npm not found: tools/node not installed (the splat-transform interop tests will skip)"; fi

# lghcc-view's renderer: viewer/web/viewer.mjs + the PlayCanvas engine -> viewer/assets/lghcc-viewer.js,
# built here once (set-up time) and inlined into every page; lghcc-view never runs npm
viewer-bundle: node-tools
	npm run --prefix tools/node build-viewer

# The JavaScript decoder as an npm package (no dependency, nothing to build: the WebAssembly is committed
# in wasm_module.mjs); tests/test_js_package.py packs and installs it the same way. Its engine loaders beside it
# (their engines and the decoder: peer dependencies)
js-package:
	mkdir -p dist
	cd js/lghcc-decoder && npm pack --pack-destination ../../dist
	cd js/lghcc-playcanvas && npm pack --pack-destination ../../dist
	cd js/lghcc-three && npm pack --pack-destination ../../dist

clean:
	rm -rf demo_out build *.egg-info

# Long decoder fuzzing (not part of `make test`): FUZZ_JOBS campaigns side by side, FUZZ_CASES in all,
# mutation of the conformance streams and of freshly encoded random scenes (tools/fuzz_scenes.py);
# nice'd, logs in fuzz_logs/, figures merged into tools/results/fuzz.md.
FUZZ_CASES ?= 1000000
FUZZ_JOBS ?= 2
FUZZ_SEED ?= 14
fuzz-long: setup
	mkdir -p fuzz_logs
	for j in $$(seq 1 $(FUZZ_JOBS)); do \
	  nice -n 19 $(PY) tools/fuzz_decoder.py --cases $$(( $(FUZZ_CASES) / $(FUZZ_JOBS) )) --scenes --timeout 60 --weigh-seeds \
	    --mutations-per-scene 100 \
	    --seed $$(( $(FUZZ_SEED) * 100 + $$j )) --failures fuzz_logs/failures_$$j --json fuzz_logs/job_$$j.json \
	    > fuzz_logs/job_$$j.log 2>&1 & \
	done; wait
	$(PY) tools/fuzz_decoder.py --merge fuzz_logs/job_*.json --out tools/results/fuzz.md

# Differential fuzzing (not part of `make test`): the reference and the JavaScript decoder on the same
# streams (tools/fuzz_differential.py; needs node), FUZZ_DIFF_JOBS campaigns side by side, FUZZ_DIFF_CASES
# in all; nice'd, logs in fuzz_logs/, merged into the differential section of tools/results/fuzz.md.
FUZZ_DIFF_CASES ?= 1000000
FUZZ_DIFF_JOBS ?= 2
fuzz-diff: setup
	mkdir -p fuzz_logs
	nice -n 19 $(PY) tools/fuzz_differential.py --cases $(FUZZ_DIFF_CASES) --jobs $(FUZZ_DIFF_JOBS) --scenes \
	  --timeout 60 --seed $$(( $(FUZZ_SEED) * 100 + 51 )) --failures fuzz_logs/diff_failures \
	  --json fuzz_logs/diff.json --checkpoint-minutes 5 --out tools/results/fuzz.md > fuzz_logs/diff.log 2>&1

# Mutation testing of the decoder against the conformance suite (conformance/mutations.py): every
# listed wrong decoder must fail some stream; rewrites the table in tools/results/conformance.md.
# Then, per condition of spec clause 8.2, the mutant without its check against its isolated stream.
mutations: setup
	nice $(PY) tools/mutation_test.py --report
	nice $(PY) tools/mutation_test.py --conditions --report

# Mutation testing of the JavaScript decoder against its conformance run (tools/js_mutation_test.py; needs node,
# and tools/node's AssemblyScript for the mutations of its WebAssembly); rewrites its section of conformance.md
js-mutations: setup node-tools
	nice $(PY) tools/js_mutation_test.py --report
