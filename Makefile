# The two commands of the README: `make demo` and `make test`. Both build .venv on first use.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
DEMO_OUT ?= demo-out
# Relative standard error of the fiber and fabric Monte Carlo in the demo (the bench runs 1%).
DEMO_REL_ERR ?= 0.03

.PHONY: demo test test-slow lint bench venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# The main job: mock acquisition of red cotton -> the reference it must recover -> the fabric BRDF
# of the same sample by the fiber model's summation, the classic baseline and the woven-fabric Monte
# Carlo at the same geometries -> comparison report (measured vs truth vs summation vs classic vs
# Monte Carlo; Figure-7 panels and colour strips) and the check of the acquisition against the truth.
# Each step prints its own time (measured figures: README, "What `make demo` does").
demo: $(STAMP)
	$(VENV)/bin/gonio demo --out $(DEMO_OUT)/measured --no-progress
	$(VENV)/bin/gonio truth red-cotton red-cotton --out $(DEMO_OUT)/truth
	$(VENV)/bin/simulate fabric red-cotton --method summation --target-rel-err $(DEMO_REL_ERR) --no-progress --out $(DEMO_OUT)/summation
	$(VENV)/bin/simulate fabric red-cotton --method classic --target-rel-err $(DEMO_REL_ERR) --no-progress --out $(DEMO_OUT)/classic
	$(VENV)/bin/simulate fabric red-cotton --method mc --target-rel-err $(DEMO_REL_ERR) --no-progress --out $(DEMO_OUT)/mc
	$(VENV)/bin/compare report $(DEMO_OUT)/measured $(DEMO_OUT)/truth $(DEMO_OUT)/summation $(DEMO_OUT)/classic $(DEMO_OUT)/mc --out $(DEMO_OUT)/report
	$(VENV)/bin/compare check $(DEMO_OUT)/measured $(DEMO_OUT)/truth --max-nrmse 0.05
	@echo "demo: report in $(DEMO_OUT)/report/report.html"

test: $(STAMP)
	$(PY) -m pytest -q -n 2 -m "not slow"

test-slow: $(STAMP)
	$(PY) -m pytest -q -n 2 -m slow

# ruff and mypy, configured in pyproject.toml (versions pinned in the test extras); .ci/run runs it
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy

bench: $(STAMP)
	$(VENV)/bin/simulate bench --out bench-out
	$(VENV)/bin/gonio bench-driver --plan red-cotton --out bench-out/driver.json

clean:
	rm -rf $(VENV) $(DEMO_OUT) bench-out .pytest_cache
