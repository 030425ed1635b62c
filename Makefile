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

.PHONY: setup test test-fast lint bench commission commission-ci clean schemas
.DELETE_ON_ERROR:

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --upgrade pip
	$(VENV)/bin/pip install --quiet -e '.[dev]'
	touch $@

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/lint-imports --no-cache

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

# ---- the commissioning chain (DESIGN §1): every step a rule on files -------------------------------
# Each `run` without --gateway starts the embedded simulated cell (ROBOT/truth.yaml) on a loopback port.
N_POSES   ?= 32
CP_PATH   ?= $(ROBOT)/paths/line-near-singularity.yaml
VAL_PATH  ?= $(ROBOT)/paths/iso9283-circle-large.yaml
RUN_SIM   := --robot $(ROBOT) --approach --interpolation-ratio 1
SELECT_OPTS ?=
EXCITE_OPTS ?=
B         := $(BUILD)
# Reads a trajectory summary's joint state for plan-ptp (the CP plan's end states).
QOF        = $$($(PY) -c "import sys, yaml; print(','.join(repr(v) for v in yaml.safe_load(open('$(1)'))['summary']['$(2)']))")

$(B)/robot-info.txt: $(STAMP) $(ROBOT)/drives.yaml | $(B)
	$(RX) robot-info $(ROBOT) > $@.part && mv $@.part $@ && cat $@

# --measure-baseline: the campaign also measures the naive set (the paper's linear scan), so the
# report shows the held-out error each pose set leaves.
$(B)/configs.yaml: $(STAMP) $(ROBOT)/drives.yaml $(CELL) | $(B)
	$(RX) select-configs --robot $(ROBOT) --cell $(CELL) -n $(N_POSES) --measure-baseline $(SELECT_OPTS) \
		--plot -o $@

# The measurement campaign: point-to-point moves need no path accuracy, so a coarse setpoint ratio.
$(B)/calib-meas.yaml: $(B)/configs.yaml
	$(RX) run $< --robot $(ROBOT) --speed 0.5 --interpolation-ratio 8 -o $@

$(B)/calibration.yaml: $(B)/calib-meas.yaml $(CELL)
	$(RX) calibrate --robot $(ROBOT) --measurements $< --cell $(CELL) --urdf-out $(B)/calibrated.urdf -o $@

$(B)/excitation.yaml: $(STAMP) $(ROBOT)/drives.yaml $(CELL) | $(B)
	$(RX) excite --robot $(ROBOT) --cell $(CELL) $(EXCITE_OPTS) --plot -o $@

$(B)/excite-log.mcap: $(B)/excitation.yaml
	$(RX) run $(B)/excitation-trajectory.mcap $(RUN_SIM) -o $@

# Validation on a different motion: an ISO 9283 path timed on the prior model.
$(B)/validation-plan.mcap: $(STAMP) $(VAL_PATH) | $(B)
	$(RX) plan-cp --robot $(ROBOT) --path $(VAL_PATH) -o $@

$(B)/validation-log.mcap: $(B)/validation-plan.mcap
	$(RX) run $< $(RUN_SIM) -o $@

$(B)/dynamics.yaml: $(B)/excite-log.mcap $(B)/validation-log.mcap
	$(RX) identify --robot $(ROBOT) --log $< --validate $(B)/validation-log.mcap --plot -o $@

$(B)/cp.mcap: $(CP_PATH) $(B)/dynamics.yaml $(B)/calibration.yaml
	$(RX) plan-cp --robot $(ROBOT) --path $(CP_PATH) --dynamics $(B)/dynamics.yaml \
		--calibration $(B)/calibration.yaml --plot -o $@

$(B)/ptp.mcap: $(B)/cp.mcap
	$(RX) plan-ptp --robot $(ROBOT) --start=$(call QOF,$(B)/cp.yaml,q_start) --goal=$(call QOF,$(B)/cp.yaml,q_goal) \
		--dynamics $(B)/dynamics.yaml --calibration $(B)/calibration.yaml --plot -o $@

# The paper's Fig. 2: the same CP plan with and without model-based feed-forward.
$(B)/run-noff.mcap: $(B)/cp.mcap
	$(RX) run $< $(RUN_SIM) --dynamics $(B)/dynamics.yaml --no-feedforward -o $@

$(B)/run-ff.mcap: $(B)/cp.mcap $(B)/run-noff.mcap
	$(RX) run $< $(RUN_SIM) --dynamics $(B)/dynamics.yaml --plot --compare $(B)/run-noff.mcap -o $@

$(B)/run-ptp.mcap: $(B)/ptp.mcap
	$(RX) run $< $(RUN_SIM) --dynamics $(B)/dynamics.yaml -o $@

$(B)/report.md: $(B)/robot-info.txt $(B)/configs.yaml $(B)/calibration.yaml $(B)/excitation.yaml \
		$(B)/dynamics.yaml $(B)/cp.mcap $(B)/ptp.mcap $(B)/run-ff.mcap $(B)/run-ptp.mcap
	$(RX) report $(B) -o $@

# The main job.
commission: $(B)/report.md
	@echo "commissioning report: $(B)/report.md"

# CI: the same chain, reduced (fewer poses and candidates, fewer excitation starts), in its own dir.
commission-ci:
	$(MAKE) commission BUILD=build-ci N_POSES=16 SELECT_OPTS="--max-candidates 1500 --restarts 2 --n-validation 16" \
		EXCITE_OPTS="--starts 2"

clean:
	rm -rf $(BUILD) build-ci
