# cablebot: the two commands are `make run` and `make test`. Each sets itself up on a fresh
# machine (creates .venv, installs the package) and is a no-op for set-up when already done.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: run test test-unit test-vcan vcan-tools bench bench-vcan chaos lint venv clean docs docs-images

venv: $(STAMP)

$(STAMP): pyproject.toml
	@echo "cablebot: setting up $(VENV) and installing the package with its extras (first run: about a minute) ..."
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	# Printrun's printcore, the printer host the G-code serial test streams with; without its
	# dependencies (they would bring a GUI toolkit: printcore needs only pyserial).
	$(PY) -m pip install -q --no-deps 'printrun==2.2.0'
	touch $(STAMP)
	@echo "cablebot: $(VENV) ready"

run: $(STAMP)
	exec $(VENV)/bin/cablebot run

# Both halves always run (a unit failure does not hide the vcan result); fails if either failed.
test: $(STAMP)
	@rc=0; $(MAKE) --no-print-directory test-unit || rc=1; \
	$(MAKE) --no-print-directory test-vcan || rc=1; exit $$rc

# tools/offhost_guard.py wraps the suites and the bench: it fails the run if any UDP (a
# udp_multicast CAN frame, Zenoh scouting) left this host through a non-loopback interface.
GUARD := $(PY) tools/offhost_guard.py --

test-unit: $(STAMP)
	$(GUARD) $(PY) -m pytest -m "not vcan" -q

# Real-SocketCAN tests (pytest -m vcan): natively when this kernel has vcan0 (or can make it),
# else inside a virtme-ng VM (tools + kernel cached in ~/.cache/cablebot, installed on first use
# without root), else a loud skip (a failure under CI=true). See tools/vcan_vm.py.
test-vcan: $(STAMP)
	$(GUARD) $(PY) tools/vcan_vm.py test

# Idempotent: apt-get the missing VM packages (as root), the virtme-ng venv, the Debian kernel.
vcan-tools:
	$(PYTHON) tools/vcan_vm.py tools --apt

bench: $(STAMP)
	$(GUARD) $(VENV)/bin/cablebot bench

# The SocketCAN I/O benchmark (fast path vs python-can's stock path) on vcan0, natively or in the
# virtme-ng VM as test-vcan; writes bench-vcan.json at the top of the checkout.
bench-vcan: $(STAMP)
	$(GUARD) $(PY) tools/vcan_vm.py bench

# The chaos run (tools/chaos, docs/chaos.md): faults on purpose against the daemon and its
# simulated drives (both families) while a client flies paths and jobs, invariants checked all
# along; CHAOS_S seconds (default 600). Network namespace, tmpfs and memory cgroup faults need
# root (else they are reported as not injected). `make test` runs a 60 s form.
CHAOS_S ?= 600
chaos: $(STAMP)
	$(GUARD) env PYTHONPATH=tools $(PY) -m chaos --duration-s $(CHAOS_S) $(CHAOS_ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check controller drivers tests tools/chaos
	$(VENV)/bin/ruff format --check controller drivers tests tools/chaos
	$(VENV)/bin/mypy
	MYPYPATH=tools $(VENV)/bin/mypy --strict -p chaos

# The configuration reference (docs/configuration.md), written from the schema in
# controller/service/config/schema.py and the drive families' options (drivers/registry.py).
docs: $(STAMP)
	$(PY) -m controller.service.config.reference --write

# The README's pictures (docs/img/circle-*.png): the paper's circle, example (c), on the simulated
# paper robot through the whole stack; about 4 minutes.
docs-images: $(STAMP)
	$(VENV)/bin/cablebot demo circle --plot docs/img

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
