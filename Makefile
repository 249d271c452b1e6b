# `make test` (the fast suite), `make test-all` (with the slow end-to-end tests; what CI runs),
# `make demo` and `make docs` (the documentation site, built strictly into build/site). Each sets
# up .venv on first use.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.trase-bench-installed
TORCH_PIN := torch==2.13.0

DOCS_STAMP := $(VENV)/.trase-bench-docs-installed
TEST_STAMP := $(VENV)/.trase-bench-test-installed

.PHONY: test test-all demo docs venv clean

venv: $(STAMP)

$(PY):
	$(PYTHON) -m venv $(VENV)

# Torch first: the pinned CPU wheel where the machine has it, so the dependency range in
# pyproject.toml is already satisfied and pip never resolves a multi-GB CUDA build.
$(STAMP): pyproject.toml $(wildcard competitors/*/pyproject.toml) | $(PY)
	@$(PY) -c "import torch" 2>/dev/null || \
	  $(PY) -m pip install --quiet "$(TORCH_PIN)" || \
	  echo "warning: $(TORCH_PIN) not available here; pip will resolve torch from pyproject.toml"
	$(PY) -m pip install --quiet -e ".[dev]"
	$(PY) -m pip install --quiet --no-deps -e competitors/trase-bench-grouping
	$(PY) -m pip install --quiet --no-deps -e competitors/trase-bench-saga
	@touch $(STAMP)

# the tests also build the text extra's models small from their configs (transformers); the
# demo and a plain install stay without it
$(TEST_STAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install --quiet -e ".[text]"
	@touch $(TEST_STAMP)

test: $(TEST_STAMP)
	$(PY) -m pytest -m "not slow"

test-all: $(TEST_STAMP)
	$(PY) -m pytest

# The main job on the built-in default data: TRASE on the synthetic HyperNeRF-format scene
# (generated once into the cache), then the leaderboard of the main runs under runs/.
demo: $(STAMP)
	$(VENV)/bin/trase-bench run --method trase --dataset hypernerf --runs runs
	$(VENV)/bin/trase-bench leaderboard --runs runs --variant synthetic

$(DOCS_STAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install --quiet -e ".[docs]"
	@touch $(DOCS_STAMP)

# strict: a broken link, a missing anchor or a page that does not build fails the build
docs: $(DOCS_STAMP)
	DISABLE_MKDOCS_2_WARNING=true $(VENV)/bin/mkdocs build --strict

clean:
	rm -rf $(VENV) build *.egg-info
