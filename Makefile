# pfdoa top-level build. Every target bootstraps what it needs (tools/bootstrap.sh).
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
BOOT := VENV=$(VENV) tools/bootstrap.sh

.PHONY: help demo test test-c test-py test-mpy firmware clean

help:
	@echo "make demo   - SIL simulator drives the gateway end to end and reports accuracy"
	@echo "make test   - all C (cmocka), MicroPython and Python tests"
	@echo "make firmware - Cortex-M4 / Cortex-M0+ images and their size table"

# Simulator (real firmware core, one instance per anchor) and gateway as separate
# processes over a pseudo-terminal: 60 s of motion at 10x, scored against ground truth.
demo:
	@$(BOOT) demo
	@$(MAKE) -s -C firmware host-lib
	$(PY) -m pfdoa -q sim --scenario demo --gateway --odom --speed 10 --duration 60 --seed 1 \
	  --faults loss=0.01,dup=0.005,reorder=0.005,ber=1e-5,drift_ppm=50 --plot build/demo.png

test: test-c test-mpy test-py

test-py:
	@$(BOOT) test
	$(PY) -m pytest tests

# C anchor core: cmocka unit, property and golden-vector tests under ASan+UBSan, plus the
# event-script harness differential check against the Python reference model.
test-c:
	@$(BOOT) test
	$(MAKE) -C firmware test PYTHON=$(abspath $(PY))

# Cortex-M4 / Cortex-M0+ images of the C core: size table, no-float proof, 4 KB budget.
firmware:
	@$(BOOT) firmware
	$(MAKE) -C firmware cortex-m

# MicroPython anchor core (unix port from the venv): unit tests and every golden vector.
test-mpy:
	@$(BOOT) test
	$(VENV)/bin/micropython firmware/micropython/tests/run_tests.py

clean:
	rm -rf build firmware/build
