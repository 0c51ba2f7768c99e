# lishield-guard: the two commands a fresh clone needs are `make run` and `make test`.
#   make run  [PORT=8000] [HOST=127.0.0.1]   install what running needs, serve the demo
#   make test                                install the dev tools too, run the test suite
#   make lock                                re-pin requirements/*.lock (pip-tools)
# Installs are pinned by the lock files (pip constraints: exactly the versions tested), while
# pyproject.toml keeps the lower bounds a library user installs against.
PY ?= python3
PORT ?= 8000
HOST ?= 127.0.0.1
VENV := .venv
BIN := $(VENV)/bin
RUN_STAMP := $(VENV)/.installed-run
DEV_STAMP := $(VENV)/.installed-dev
RUN_LOCK := requirements/run.lock
DEV_LOCK := requirements/dev.lock
IS_ROOT := $(shell [ "$$(id -u)" = 0 ] && echo yes)

.PHONY: run test lint bench clean venv tools mutants train lock

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# What running needs: the package and its runtime dependencies, nothing else, at the versions
# of requirements/run.lock.
$(RUN_STAMP): pyproject.toml $(RUN_LOCK) | $(BIN)/python
	$(BIN)/python -m pip install --quiet -c $(RUN_LOCK) -e .
	touch $@

# Tests: the runtime plus the `dev` extra (pytest, hypothesis, httpx, selenium, ...), at the
# versions of requirements/dev.lock.
$(DEV_STAMP): pyproject.toml $(DEV_LOCK) $(RUN_STAMP)
	$(BIN)/python -m pip install --quiet -c $(DEV_LOCK) -e '.[dev]'
	touch $@

# Re-pin the lock files from pyproject.toml's bounds (after changing a dependency).
PIP_COMPILE = $(BIN)/pip-compile --quiet --strip-extras --no-emit-index-url \
	--no-emit-find-links --no-emit-trusted-host --annotation-style line
lock: | $(BIN)/python
	$(BIN)/python -m pip install --quiet 'pip-tools>=7.4'
	$(PIP_COMPILE) --output-file $(RUN_LOCK) pyproject.toml
	$(PIP_COMPILE) --extra dev --output-file $(DEV_LOCK) pyproject.toml

venv: $(RUN_STAMP)

run: $(RUN_STAMP)
	$(BIN)/python scripts/demo.py --host $(HOST) --port $(PORT)

# System tools some tests use. Installed with apt-get only when really missing and when root;
# otherwise say what is missing and let those tests skip with their reason.
tools:
	@if ! command -v cc >/dev/null 2>&1; then \
	  if [ "$(IS_ROOT)" = yes ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing a C compiler (firmware player tests)"; \
	    apt-get update -qq && apt-get install -y -qq gcc libc6-dev >/dev/null; \
	  else echo "note: no C compiler (cc); the firmware player tests will be skipped." \
	    "Install gcc, or run make test as root on Debian/Ubuntu."; fi; fi
	@if ! command -v chromedriver >/dev/null 2>&1 || \
	    ! { command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; }; then \
	  if [ "$(IS_ROOT)" = yes ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing chromium and chromium-driver (reviewer-page browser test)"; \
	    apt-get update -qq && apt-get install -y -qq chromium chromium-driver >/dev/null; \
	  else echo "note: no chromium/chromedriver; the reviewer-page browser test will be" \
	    "skipped. Install them (Debian: apt-get install chromium chromium-driver)."; fi; fi

test: $(DEV_STAMP) tools
	$(BIN)/python -m pytest -q -p no:cacheprovider

# One-line mutants of the pass rules, look-alike defences and scan --resume, each run in a
# temporary copy against the tests named after it (docs/testing.md); lists the survivors.
mutants: $(DEV_STAMP)
	$(BIN)/python scripts/mutate_rules.py

# The docs' generated blocks (README's sample output of `detect` on the demo images, figure
# captions, exit statuses; design.md's captions; docs/service.md's error-code table), every
# generated figure and the reviewer-page screenshot, from the current code. `make docs-check`
# (scripts/make_docs.py --check) writes nothing: it exits 1 when a block, a figure, the
# screenshot or a command written in the docs is stale.
.PHONY: docs docs-check
docs: $(DEV_STAMP)
	$(BIN)/python scripts/make_docs.py

docs-check: $(DEV_STAMP)
	$(BIN)/python scripts/make_docs.py --check

# Reproduce the shipped decision weights (docs/training.md): the photo corpus, the scene bank,
# 102000 training examples of seed 40 (profile-domain renderer, cached and resumable in
# out/train/data), the network (6 passes) and its report. The training extra (torch, CPU
# build) is installed here only. On 2 cores: about 85 minutes of data and 10-30 minutes of
# training. More cores or a GPU: TRAIN_ARGS='--jobs 16 --device cuda --batch 512'.
TRAIN_ARGS ?=
TRAIN_STAMP := $(VENV)/.installed-train
$(TRAIN_STAMP): pyproject.toml $(RUN_STAMP)
	$(BIN)/python -m pip install --quiet -e '.[train]'
	touch $@

train: $(TRAIN_STAMP)
	$(BIN)/python scripts/fetch_photos.py
	$(BIN)/python -m training.scenes
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m training.train --n 102000 --seed 40 --epochs 6 \
	  --out out/train/model $(TRAIN_ARGS)
	$(BIN)/python -m training.report --model out/train/model/decision_model.npz

lint: $(DEV_STAMP)
	$(BIN)/ruff check .

bench: $(RUN_STAMP)
	$(BIN)/lishield-guard bench --quick

clean:
	rm -rf $(VENV) build *.egg-info
