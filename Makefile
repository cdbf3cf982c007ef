# pfdoa top-level build. Every target bootstraps what it needs (tools/bootstrap.sh).
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
BOOT := VENV=$(VENV) tools/bootstrap.sh

.PHONY: help demo demo-qemu demo-fleet check test test-fast test-c test-c-unit test-py test-mpy lint firmware flash eval eval-sites eval-synthetic fuzz bench clean

help:
	@echo "make demo   - SIL simulator drives the gateway end to end and reports accuracy"
	@echo "make test   - all C (cmocka), MicroPython and Python tests (every tier)"
	@echo "make check  - the developer's loop: lint, the Python unit tier (tests/unit) and the C core's cmocka tests"
	@echo "make test-fast - the Python unit tier only (tests/unit)"
	@echo "make lint   - static checks: ruff (Python), mypy (host/, sim/, tools/, bench/), cppcheck (firmware); make test runs it"
	@echo "make firmware - Cortex-M4 / Cortex-M0+ images, the QEMU and nRF52840 ports, size tables"
	@echo "make flash BOARD=nrf52840dk [IMAGE=uart|can|154|beacon] [ANCHOR_ID=N] - flash a board with pyocd"
	@echo "make demo-qemu - four QEMU Cortex-M3 anchors (the firmware image) feed the gateway"
	@echo "make demo-fleet - a local mosquitto, simulated ESPresense nodes and beacons, the gateway over MQTT; per-beacon accuracy"
	@echo "make fuzz   - libFuzzer (firmware decoders) + atheris (gateway), FUZZ_SECONDS=30 per target"
	@echo "make eval   - reproduce the paper's Table I: docs/results.md and docs/img/*.png (minutes)"
	@echo "make eval-sites - every real site judged like a deployment (one calibration walk, uncalibrated): docs/sites.md"
	@echo "make eval-synthetic - the same on synthetic rooms with place-fixed deviations: docs/synthetic-sites.md"
	@echo "make bench  - benchmarks: build/bench.json and build/bench.md (docs/benchmarks.md; ~3 min)"

# Simulator (real firmware core, one instance per anchor) and gateway as separate
# processes, in virtual time, as a deployment goes: three 60 s calibration walks through
# the room recorded with ground truth and fitted by `pfdoa calibrate`, then 60 s of motion
# with link faults, anchor clock drift and transport jitter on the fitted site, scored
# against ground truth (error, and how often the truth lies within r95 and the covariance's
# 95 % ellipse). The same seed prints the same summary.
demo:
	@$(BOOT) demo
	@$(MAKE) -s -C firmware host-lib
	$(PY) -m pfdoa -q sim --scenario demo --gateway --odom --duration 60 --seed 1 --calibrate 3 \
	  --faults loss=0.01,dup=0.005,reorder=0.005,ber=1e-5,drift_ppm=50,jitter=20 --plot build/demo.png

# Fleets over MQTT (docs/fleet.md): a local mosquitto (127.0.0.1, a free port, generated
# config), the pfdoa gateway process reading ESPresense nodes' messages (--mqtt-input
# espresense) on the site file the simulator writes, 8 nodes reporting 4 walking beacons in
# simulated time; every pose on the broker scored against the truth. Seeds 1-3, no
# odometry, the radio model known (in-sample). The same seeds print the same summary.
demo-fleet:
	@$(BOOT) fleet
	$(PY) -m pfdoasim.fleet --site examples/espresense/site.toml --seeds 1,2,3

# The Cortex-M3 firmware image in the loop: four QEMU mps2-an385 anchors, each on its own
# pseudo-terminal, fed RADIO_INJECT frames from the simulator's radio model, their output
# checked byte for byte against the host build live and streamed to the gateway in
# virtual time; positions and their errors against ground truth are printed.
demo-qemu:
	@$(BOOT) qemu
	@$(MAKE) -s -C firmware/ports/qemu_mps2
	$(PY) -m pfdoa -q sim --scenario demo --anchor-backend qemu --gateway --odom --duration 60 \
	  --seed 1 --plot build/demo-qemu.png

test: lint test-c test-mpy test-py

# Static checks, configured in pyproject.toml ([tool.ruff], [tool.mypy]) and
# firmware/Makefile (cppcheck over the core, host tools and every port). Before committing:
# `make lint`; `.venv/bin/ruff check --fix .` sorts imports and drops unused ones.
lint:
	@$(BOOT) lint
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy
	$(MAKE) -s -C firmware lint

# Two pytest-xdist workers: the CI machine's two cores (tests/conftest.py says which tests
# take turns). PYTEST_WORKERS=0 runs in one process. Tiers are folders (tests/unit, io, sil,
# firmware, qemu); a unit test over its CPU budget fails (tests/conftest.py); the 15 slowest
# tests are listed at the end.
PYTEST_WORKERS ?= 2
test-py:
	@$(BOOT) test dds
	$(PY) -m pytest tests -n $(PYTEST_WORKERS) --durations=15

# The developer's loop before a commit (CONTRIBUTING.md): static checks, the Python unit tier
# and the C core's cmocka tests under ASan+UBSan. `make test` runs every tier.
check: lint test-fast test-c-unit

# The unit tier: in-process, no real time, each test within its CPU budget.
test-fast:
	@$(BOOT) test
	$(PY) -m pytest tests/unit -n $(PYTEST_WORKERS)

# C anchor core: cmocka unit, property and golden-vector tests under ASan+UBSan, plus the
# event-script harness differential check against the Python reference model.
test-c:
	@$(BOOT) test
	$(MAKE) -C firmware test PYTHON=$(abspath $(PY))

# The C core's cmocka tests alone (no fuzz replays, differential check or nRF52840 port).
test-c-unit:
	@$(BOOT) test
	$(MAKE) -s -C firmware unit PYTHON=$(abspath $(PY))

# Cortex-M4 / Cortex-M0+ images of the C core: size table, no-float proof, 4 KB budget.
firmware:
	@$(BOOT) firmware
	$(MAKE) -C firmware cortex-m
	@echo "== QEMU mps2-an385 (Cortex-M3) port: SIL, production and port self-test images"
	@$(MAKE) -s -C firmware/ports/qemu_mps2 size
	@echo "== nRF52840 (Cortex-M4, DK PCA10056) port: UART, CAN (MCP2515) and IEEE 802.15.4 anchor images, the authenticated beacon image"
	@$(MAKE) -s -C firmware/ports/nrf52840 size

# Flash a board (firmware/ports/README.md). pyocd comes from PyPI into the venv on first use.
BOARD ?=
flash:
	@case "$(BOARD)" in nrf52840dk) ;; *) echo "flash: BOARD=nrf52840dk is the board this knows (got '$(BOARD)')"; exit 2;; esac
	@$(BOOT) firmware
	@$(VENV)/bin/python -c 'import pyocd' 2>/dev/null || $(VENV)/bin/pip install -q pyocd
	@$(MAKE) -s -C firmware/ports/nrf52840 flash PYOCD=$(abspath $(VENV))/bin/pyocd PYTHON=$(abspath $(PY)) \
	  IMAGE=$(or $(IMAGE),uart) ANCHOR_ID=$(or $(ANCHOR_ID),1)

# MicroPython anchor core (unix port from the venv): unit tests and every golden vector.
test-mpy:
	@$(BOOT) test
	$(VENV)/bin/micropython firmware/micropython/tests/run_tests.py

# The paper's Table I (Datasets 0/1/2) and the robot traces, every estimator, fixed seeds.
eval:
	@$(BOOT) demo
	$(PY) -m pfdoa eval --jobs 2 --out docs/results.md --plots docs/img

# Every real site judged like a deployment (pfdoa.evaluation.deployment): each run calibrated
# on one other run alone, every ordered pair, and uncalibrated; every method, seeds 0-9, with
# and without odometry where a site has it; per-site ratios worst first, held-out sites apart.
# The committed sites (host/pfdoa/data) and, where converted, the local ones in SITES_LOCAL
# (datasets that state no licence: tools/convert_ble51.py CHECKOUT build/sites, see
# host/pfdoa/data/README.md); SITES= adds folders of your own sites. The comparison methods'
# results are kept in build/eval-cache by content (a rerun after a pf-doa change recomputes pf-doa only).
SITES_LOCAL ?= build/sites
SITES ?=
eval-sites:
	@$(BOOT) demo
	$(PY) -m pfdoa eval --sites host/pfdoa/data $(if $(wildcard $(SITES_LOCAL)/*/*.csv*),$(SITES_LOCAL)) $(SITES) --calibration walk --jobs 2 \
	  --cache build/eval-cache --out docs/sites.md

# The same protocol on synthetic rooms whose anchors have place-fixed deviations (walls), a
# failure mode the real development sites show little of (tools/synthetic_sites.py --walls).
eval-synthetic:
	@$(BOOT) demo
	$(PY) tools/synthetic_sites.py build/synthetic --seed 1 --walls
	$(PY) -m pfdoa eval --sites build/synthetic --calibration walk --jobs 2 --cache build/eval-cache \
	  --out docs/synthetic-sites.md

# Fuzzing (docs/security.md): libFuzzer + ASan/UBSan on the firmware's decoders, atheris
# on the gateway's parsers, FUZZ_SECONDS each from fuzz/corpus/; a summary line per target.
FUZZ_SECONDS ?= 30
fuzz:
	@$(BOOT) fuzz
	@$(PY) -c 'import atheris' 2>/dev/null || $(VENV)/bin/pip install -q -e '.[fuzz]'
	$(PY) fuzz/run.py --seconds $(FUZZ_SECONDS)

# Estimator step, gateway throughput/latency/memory, firmware size and instruction counts.
bench:
	@$(BOOT) bench
	$(PY) -m bench.run --out build/bench.json --md build/bench.md

clean:
	rm -rf build firmware/build
