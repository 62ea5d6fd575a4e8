# dualtalker-lite: every target creates/reuses the virtual environment .venv itself.
#   make lab    open JupyterLab on notebooks/         (main job, interactive)
#   make demo   headless end-to-end run -> runs/demo/ (main job, no browser)
#   make test   every test CI runs: installs the test tools it can first (make test-tools), then the unit tests, the
#               tests that need those tools and nbval over every notebook; lists every skipped test at the end
#   make unit   the quick check: tests/ without the notebooks and without the tests that need test tools
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
export OMP_NUM_THREADS ?= 2
export MPLBACKEND ?= Agg

.PHONY: lab demo test test-tools unit nbval env sample bench clean katex

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# torch first, the CPU build where it can be had (tools/install_torch.py says which and how much it
	# downloads): with torch 2.13.0 present, nothing else pulls CUDA packages.
	$(PY) tools/install_torch.py
	$(PY) -m pip install --quiet -e ".[notebooks,speech,phonetic,live,dev]"
	touch $(STAMP)

env: $(STAMP)

# Jupyter refuses to run as root unless told to (containers, CI-like machines): allow it there only.
LAB_FLAGS ?= $(if $(filter 0,$(shell id -u)),--allow-root,)

lab: $(STAMP)
	$(VENV)/bin/jupyter lab $(LAB_FLAGS) notebooks/

demo: $(STAMP)
	$(PY) -m dualtalker_lite.demo --out runs/demo

# What CI runs (.ci/run is `make test`). tools/test_tools.sh installs the test tools this machine allows (npm
# packages into the checkout; chromium and the real recordings with apt-get, as root only), prints one line per tool
# still missing with the command that installs it, and runs pytest with DUALTALKER_REQUIRE_*=1 for every tool present
# (those tests then fail instead of skipping). pytest's summary (-ra, pyproject.toml) lists every skipped test with its
# reason; any pytest failure, "no tests collected" (status 5) included, fails make.
test: $(STAMP)
	bash tools/test_tools.sh $(PY) -m pytest tests notebooks --nbval-lax --durations=15

test-tools:
	bash tools/test_tools.sh

# The quick check while editing: no notebooks, no installs, none of the tests marked `tools` (the glTF validator,
# three.js, KaTeX, the browser and the real recordings; pyproject.toml's markers).
unit: $(STAMP)
	$(PY) -m pytest tests -m "not tools"

nbval: $(STAMP)
	$(PY) -m pytest notebooks --nbval-lax

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

clean:
	rm -rf $(VENV) runs .pytest_cache
