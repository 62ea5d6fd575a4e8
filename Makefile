# dualtalker-lite: every target creates/reuses the virtual environment .venv itself.
#   make lab    open JupyterLab on working copies of notebooks/ in runs/notebooks/ (main job, interactive)
#   make demo   headless end-to-end run -> runs/demo/ (main job, no browser); options: make demo ARGS="--seed 1"
#   make test   every test CI runs: installs the test tools it can first (make test-tools), then the unit tests, the
#               tests that need those tools and nbval over every notebook; lists every skipped test at the end
#   make unit   the quick check: tests/ without the notebooks and without the tests that need test tools
#   make gpu-check  the GPU check (benchmarks/gpu.py -> results/gpu.md); one line and exit 0 without CUDA
# make test, unit and nbval run pytest in TEST_JOBS worker processes (pytest-xdist; default: the cores present,
# `make test TEST_JOBS=1` for one process), each with one torch/OpenMP thread: tests are small tensors and
# subprocesses, so a process per core beats threads in one process (docs/testing.md).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
export OMP_NUM_THREADS ?= 2
export MPLBACKEND ?= Agg
TEST_JOBS ?= $(shell nproc 2>/dev/null || echo 2)
# --dist loadscope: a test module (a notebook: its cells) runs whole on one worker, so module fixtures are built once
# and a notebook's cells run in order in one kernel
XDIST  := -n $(TEST_JOBS) --dist loadscope

.PHONY: lab demo test test-tools unit nbval env sample bench gpu-check clean katex fuzz

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# torch first, the CPU build where it can be had (tools/install_torch.py says which and how much it
	# downloads): with torch 2.13.0 present, nothing else pulls CUDA packages.
	$(PY) tools/install_torch.py
	$(PY) -m pip install --quiet -e ".[notebooks,speech,phonetic,live,cluster,dev]"
	touch $(STAMP)

env: $(STAMP)

# Jupyter refuses to run as root unless told to (containers, CI-like machines): allow it there only.
LAB_FLAGS ?= $(if $(filter 0,$(shell id -u)),--allow-root,)

# JupyterLab saves what it runs: it opens working copies in runs/notebooks/ (tools/lab.py), never notebooks/
lab: $(STAMP)
	$(PY) tools/lab.py --out runs/notebooks
	$(VENV)/bin/jupyter lab $(LAB_FLAGS) runs/notebooks/

demo: $(STAMP)
	$(PY) -m dualtalker_lite.demo --out runs/demo $(ARGS)

# What CI runs (.ci/run is `make test`). tools/test_tools.sh installs the test tools this machine allows (npm
# packages into the checkout; chromium and the real recordings with apt-get, as root only), prints one line per tool
# still missing with the command that installs it, and runs pytest with DUALTALKER_REQUIRE_*=1 for every tool present
# (those tests then fail instead of skipping). pytest's summary (-ra, pyproject.toml) lists every skipped test with its
# reason; any pytest failure, "no tests collected" (status 5) included, fails make.
test: $(STAMP)
	OMP_NUM_THREADS=1 bash tools/test_tools.sh $(PY) -m pytest tests notebooks --nbval-lax $(XDIST) --durations=25

test-tools:
	bash tools/test_tools.sh

# The quick check while editing: no notebooks, no installs, none of the tests marked `tools` (the glTF validator,
# three.js, KaTeX, the browser and the real recordings; pyproject.toml's markers).
unit: $(STAMP)
	OMP_NUM_THREADS=1 $(PY) -m pytest tests -m "not tools" $(XDIST)

# The property tests of tests/test_fuzz.py (mutated checkpoint configs, front-end settings, WAV headers, output
# manifests) with random examples, round after round (a new seed each), for FUZZ_SECONDS (the last round may run
# over); failures are kept in .hypothesis/ and replayed first. In the suite they run derandomized, a few seconds.
FUZZ_SECONDS ?= 600
fuzz: $(STAMP)
	end=$$(( $$(date +%s) + $(FUZZ_SECONDS) )); seed=0; \
	while [ $$(date +%s) -lt $$end ]; do \
	  OMP_NUM_THREADS=1 $(PY) -m pytest tests/test_fuzz.py -q --hypothesis-profile fuzz \
	    --hypothesis-seed=$$seed || exit 1; seed=$$((seed + 1)); \
	done; echo "fuzz: $$seed rounds, no failure"

nbval: $(STAMP)
	OMP_NUM_THREADS=1 $(PY) -m pytest notebooks --nbval-lax $(XDIST)

# KaTeX (pinned by tools/katex/package-lock.json, ~1 MB) for tests/test_notebook_math.py, which renders every
# formula of the notebooks as JupyterLab's KaTeX would; without it that test is skipped (make test-tools installs it
# with the other test tools; CI requires it).
katex:
	npm ci --prefix tools/katex --no-audit --no-fund --loglevel=error

# Regenerate the shipped sample bit for bit (needs the [speech] extra, installed by default). Built in a
# temporary folder and swapped in when complete, so no stale clip survives and a failure leaves the old sample.
sample: $(STAMP)
	rm -rf runs/sample.tmp
	$(PY) -m dualtalker_lite.data.generate --preset sample --out runs/sample.tmp
	cp data_samples/README.md runs/sample.tmp/
	rm -rf data_samples && mv runs/sample.tmp data_samples

bench: $(STAMP)
	$(PY) benchmarks/run_all.py

# The GPU check (benchmarks/gpu.py): the CUDA tests, the four papers' models at their paper() sizes for a few hundred
# steps with and without --amp, and animate --device cuda of an hour -> results/gpu.md. Without CUDA: one line, exit 0.
gpu-check: $(STAMP)
	$(PY) benchmarks/gpu.py

clean:
	rm -rf $(VENV) runs .pytest_cache
