# Two commands on a fresh machine: `make demo` and `make test`. Both create .venv if missing.
# CUDA users: `make TORCH="torch" install` (or any torch build of your choice) before the rest.
PYTHON ?= python3
VENV ?= .venv
TORCH ?= torch==2.13.0
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install test test-slow lint demo demo-finetune bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q "$(TORCH)"
	$(BIN)/python -m pip install -q -e ".[test]"
	touch $(STAMP)

install: $(STAMP)

lint: $(STAMP)
	$(BIN)/ruff check spikegyro tests bench

test: lint
	$(BIN)/python -m pytest -q

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

demo: $(STAMP)
	$(BIN)/spikegyro demo

# The demo plus a few minutes of CPU fine-tuning of the shipped weights at full resolution.
demo-finetune: $(STAMP)
	$(BIN)/spikegyro demo --finetune-minutes 5

# The CPU benchmarks that run on their own; gpu_step.py (CUDA), nir_snntorch.py and
# roll_readout.py (datasets to pass) are run with the commands in BENCHMARKS.md.
CPU_BENCHES := simulator snn_step streaming cmax formats

bench: $(STAMP)
	$(BIN)/python -m pip install -q -e ".[test,bench]"
	for b in $(CPU_BENCHES); do $(BIN)/python bench/$$b.py || exit 1; done

clean:
	rm -rf $(VENV) demo-output .pytest_cache .ruff_cache
