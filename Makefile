# Two commands on a fresh machine: `make demo` and `make test`. Both create .venv if missing.
# CUDA users: `make TORCH="torch" install` (or any torch build of your choice) before the rest.
PYTHON ?= python3
VENV ?= .venv
TORCH ?= torch==2.13.0
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DOCS_STAMP := $(VENV)/.docs-installed

.PHONY: install test test-slow lint docs demo demo-finetune bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q "$(TORCH)"
	$(BIN)/python -m pip install -q -e ".[test]"
	touch $(STAMP)

install: $(STAMP)

# ruff, and the layers of docs/layout.md (import-linter's contracts in pyproject.toml).
lint: $(STAMP)
	$(BIN)/ruff check spikegyro tests bench scripts
	$(BIN)/lint-imports

# The documentation site (MkDocs) into site/; --strict turns every warning into an error.
$(DOCS_STAMP): $(STAMP)
	$(BIN)/python -m pip install -q -e ".[test,docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

test: lint docs
	$(BIN)/python -m pytest -q

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

demo: $(STAMP)
	$(BIN)/spikegyro demo

# The demo plus a few minutes of CPU fine-tuning of the shipped weights at full resolution.
demo-finetune: $(STAMP)
	$(BIN)/spikegyro demo --finetune-minutes 5

# The CPU benchmarks that run on their own; gpu_step.py (CUDA), nir_snntorch.py and
# the analysis scripts in scripts/analysis/ (datasets to pass) are run with the commands in
# BENCHMARKS.md and docs/analysis.md.
CPU_BENCHES := simulator snn_step streaming cmax formats train_step

bench: $(STAMP)
	$(BIN)/python -m pip install -q -e ".[test,bench]"
	for b in $(CPU_BENCHES); do $(BIN)/python bench/$$b.py || exit 1; done

clean:
	rm -rf $(VENV) demo-output site .pytest_cache .ruff_cache
