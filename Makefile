# cablebot: the two commands are `make run` and `make test`. Each sets itself up on a fresh
# machine (creates .venv, installs the package) and is a no-op for set-up when already done.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: run test test-unit test-vcan bench lint venv clean docs-images

venv: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)
	exec $(VENV)/bin/cablebot run

test: test-unit test-vcan

test-unit: $(STAMP)
	$(PY) -m pytest -m "not vcan" -q

test-vcan: $(STAMP)
	@echo "vcan suite: not wired yet"

bench: $(STAMP)
	$(VENV)/bin/cablebot bench

lint: $(STAMP)
	$(VENV)/bin/ruff check controller drivers tests
	$(VENV)/bin/ruff format --check controller drivers tests
	$(VENV)/bin/mypy

# The README's pictures (docs/img/circle-*.png): the paper's circle, example (c), on the simulated
# paper robot through the whole stack; about 4 minutes.
docs-images: $(STAMP)
	$(VENV)/bin/cablebot demo circle --plot docs/img

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
