# lishield-guard: the two commands a fresh clone needs are `make run` and `make test`.
#   make run  [PORT=8000] [HOST=127.0.0.1]   install what running needs, serve the demo
#   make test                                install the dev tools too, run the test suite
PY ?= python3
PORT ?= 8000
HOST ?= 127.0.0.1
VENV := .venv
BIN := $(VENV)/bin
RUN_STAMP := $(VENV)/.installed-run
DEV_STAMP := $(VENV)/.installed-dev
IS_ROOT := $(shell [ "$$(id -u)" = 0 ] && echo yes)

.PHONY: run test lint bench clean venv tools mutants train

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# What running needs: the package and its runtime dependencies, nothing else.
$(RUN_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

# Tests: the runtime plus the `dev` extra (pytest, hypothesis, httpx, selenium, ...).
$(DEV_STAMP): pyproject.toml $(RUN_STAMP)
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $@

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

# The README's generated blocks (sample output of `detect` on the demo images, figure captions,
# exit statuses), docs/service.md's error-code table and docs/figures/verdict_*.png, from the
# current code; `scripts/make_docs.py --check` says whether they are stale without writing.
.PHONY: docs
docs: $(DEV_STAMP)
	$(BIN)/python scripts/make_docs.py

# Reproduce the shipped decision weights (docs/training.md): the photo corpus, the scene bank,
# 17200 training examples of seed 32 (cached in out/train/data), the network and its report.
# The training extra (torch, CPU build; scikit-learn) is installed here only. On 2 cores:
# about 30 minutes of data and 1.5 hours of training; with a GPU, minutes.
TRAIN_STAMP := $(VENV)/.installed-train
$(TRAIN_STAMP): pyproject.toml $(RUN_STAMP)
	$(BIN)/python -m pip install --quiet -e '.[train]'
	touch $@

train: $(TRAIN_STAMP)
	$(BIN)/python scripts/fetch_photos.py
	$(BIN)/python -m training.scenes
	$(BIN)/python -m training.train --n 17200 --seed 32 --epochs 20 --out out/train/model \
	  --runner-up
	$(BIN)/python -m training.report --model out/train/model/decision_model.npz

lint: $(DEV_STAMP)
	$(BIN)/ruff check .

bench: $(RUN_STAMP)
	$(BIN)/lishield-guard bench --quick

clean:
	rm -rf $(VENV) build *.egg-info
