# pfdoa top-level build. Every target bootstraps what it needs (tools/bootstrap.sh).
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
BOOT := VENV=$(VENV) tools/bootstrap.sh

.PHONY: help demo test test-py firmware clean

help:
	@echo "make demo   - SIL simulator drives the gateway end to end and reports accuracy"
	@echo "make test   - all C (cmocka), MicroPython and Python tests"
	@echo "make firmware - Cortex-M4 / Cortex-M0+ images and their size table"

demo:
	@$(BOOT) demo
	$(PY) -m pfdoa --help

test: test-py

test-py:
	@$(BOOT) test
	$(PY) -m pytest tests

clean:
	rm -rf build
