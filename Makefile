# rxcomm: the commissioning chain as make rules on files, plus setup/test/bench.
# `make commission` runs the chain against the embedded simulated cell; `make test` runs lint + tests.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
RX     := $(VENV)/bin/rxcomm
ROBOT  ?= samples/rx130l
CELL   ?= $(ROBOT)/cell.yaml
BUILD  ?= build
STAMP  := $(VENV)/.installed

.PHONY: setup test test-fast test-all lint bench commission clean schemas

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --upgrade pip
	$(VENV)/bin/pip install --quiet -e '.[dev]'
	touch $@

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

# The README's test command: lint, then every test (slow end-to-end ones included).
test: lint
	$(VENV)/bin/pytest -q -p no:cacheprovider; rc=$$?; [ $$rc -eq 5 ] && rc=0; exit $$rc

# Unit tests only, for the edit-run loop.
test-fast: $(STAMP)
	$(VENV)/bin/pytest -q -m "not slow" -p no:cacheprovider

schemas: $(STAMP)
	$(PY) -m rxcomm.schemas.generate

bench: $(STAMP)
	$(PY) -m bench

$(BUILD):
	mkdir -p $@

$(BUILD)/robot-info.txt: $(STAMP) $(ROBOT)/drives.yaml | $(BUILD)
	$(RX) robot-info $(ROBOT) > $@.part && mv $@.part $@ && cat $@

# The main job; grows with each stage.
commission: $(BUILD)/robot-info.txt

clean:
	rm -rf $(BUILD)
