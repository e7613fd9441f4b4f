# The two commands of the README: `make demo` and `make test`. Both build .venv on first use.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
DEMO_OUT ?= demo-out
# Relative standard error of the fiber and fabric Monte Carlo in the demo (the bench runs 1%).
DEMO_REL_ERR ?= 0.03
# The measured sample: the real green felt of the RGL database (fixtures/real/, CC0), put into the
# mock goniophotometer; the plan of the file's own measured incidences (0, 27.76, 40.03, 50.16, 59.52,
# 68.77, 78.56 deg: no incidence interpolated between its tables) with green-felt's in-plane curves and
# the retro-reflection rings 6 and 30 deg from the source (gonio.acquisition.plan.measured_plan;
# docs/notes/fit-trust.md). green-felt asks for 30/45/60 deg, the file's interpolation.
DEMO_SAMPLE ?= fixtures/real/acrylic_felt_green_rgb.bsdf
DEMO_PLAN ?= measured
# The config the fits start from: the green-felt preset (simulate/configs/green-felt.toml: the felt
# structure, RMS slope and scatterers fitted to this felt once). DEMO_DYE: the dye replaced by 8
# knots started from the measured colour (any start config turns green; empty keeps the start's dye).
DEMO_START ?= green-felt
# The classic model's start: red cotton (its dye becomes knots as well). The classic model is the top
# cell's carpet without the felt's layers, so the felt preset's clear fibers are a poor start for it
# (NRMSE 0.335 against 0.229 from red cotton; README, fit section).
DEMO_CLASSIC_START ?= red-cotton
DEMO_DYE ?= --dye knots
DEMO_FREE ?= dye,rms_slope
# The Monte Carlo fit (output space mapping, fabric_optics/fitting/mc.py): its start config, free parameters and
# budget of Monte Carlo runs (the start's included; its initial/ is the Monte Carlo at the start).
# It starts from the felt as the Monte Carlo fitted it once (simulate/configs/green-felt-mc.toml:
# clear fibers, volume fraction 0.00085, a fiber boundary rough for transmitted light, traced converged
# at [10, 20] exit bins), not from the summation's fit: the summation's optimum
# (volume fraction 0.003) is biased by its missing forward transport, and the space mapping, which
# borrows the summation's trend, does not leave it (README "What make demo does").
DEMO_MC_START ?= green-felt-mc
DEMO_MC_FREE ?= dye
DEMO_MC_RUNS ?= 2
# The plan of the Monte Carlo fit's preparation (DEMO_MC_PREPARE): any plan at the measurement's wavelengths
# (the tables and the walk depend on the wavelengths, not on the geometries); green-felt's are the measured plan's.
DEMO_MC_PREPARE_PLAN ?= green-felt
# A fit whose colour is left off exits 3 with its outputs written and labelled failing
# (docs/notes/fit-trust.md); the demo goes on so that the report shows it. Any other failure stops it.
FIT_VERDICT = || [ $$? -eq 3 ]
# Evaluation budget of each fit (one walk each, then the evaluations): the default, more than the classic
# and summation fits need to converge on the demo's acquisition with the colour held (docs/notes/fit-trust.md,
# "The fits on the measured plan").
DEMO_FIT_EVALS ?= 800
# Relative standard error of each fit's first Monte Carlo walk (the start configs' own differ).
DEMO_FIT_REL_ERR ?= 0.03

.PHONY: demo test test-slow lint bench venv clean docs figures reference browser architecture

venv: $(STAMP)

# The environment, from pyproject.toml's pins, by uv (https://docs.astral.sh/uv/: its resolver and parallel,
# cached installs take seconds where pip takes a minute or more): the uv on PATH, or else the pinned UV_VERSION,
# which pip first installs into the new venv (one wheel); pip installs the project if uv cannot.
# `make venv INSTALLER=pip` uses pip alone. The venv has pip either way, for the README's
# `pip install -e '.[render]'`. Modules are compiled to bytecode at install, as pip does, so that the
# first run's processes do not each compile them. `make demo` needs the project alone (BASE_STAMP);
# the test, lint and docs targets add the test and docs extras to the same venv (STAMP).
UV ?= $(shell command -v uv 2>/dev/null)
UV_VERSION ?= 0.13.10
INSTALLER ?= uv
BASE_STAMP := $(VENV)/.installed-base-stamp
UV_IN_VENV := $(VENV)/bin/uv
EXTRAS := .[test,docs]
# $(call install,SPEC): install the project (editable) with SPEC's extras into the venv
ifeq ($(INSTALLER),pip)
install = $(PY) -m pip install --quiet -e '$(1)'
else
install = $(if $(strip $(UV)),$(UV),$(UV_IN_VENV)) pip install --quiet --compile-bytecode --python $(PY) -e '$(1)' \
	|| $(PY) -m pip install --quiet -e '$(1)'
endif

$(PY):
ifeq ($(INSTALLER),pip)
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
else ifneq ($(strip $(UV)),)
	$(UV) venv --quiet --seed --allow-existing --python $(PYTHON) $(VENV)
else
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet 'uv==$(UV_VERSION)' || true
endif

$(BASE_STAMP): pyproject.toml | $(PY)
	$(call install,.)
	touch $(BASE_STAMP)

$(STAMP): $(BASE_STAMP)
	$(call install,$(EXTRAS))
	touch $(STAMP)

# The main job (README, "What `make demo` does"): the real felt measured through the mock instrument
# on its real protocol endpoints -> the file itself at the plan's geometries (the truth) and the
# check of the acquisition against it (guards the driver) -> red cotton, the simulated seed sample,
# by the summation, judged against its published colour -> the classic model and the summation
# fitted to the acquisition -> the felt Monte Carlo, its dye refitted from its own felt preset ->
# report: measured vs truth vs fitted classic, summation and Monte Carlo, what was measured, the
# fitted parameters with their uncertainties, the seed sample's colour check.
# Steps that do not need each other's outputs run side by side, two at a time (one per core of a
# 2-core machine): red cotton beside the acquisition, the Monte Carlo fit beside the classic and
# summation fits. A line of two waits for both and fails when either failed (a fit's exit 3 included
# as FIT_VERDICT says). Each step prints its own time (measured figures: README, "What `make demo`
# does"). Each step replaces the previous demo's output (--force).
# The acquisition leaves a core idle: beside it and red cotton, DEMO_MC_PREPARE makes what the Monte
# Carlo fit would make before and between its runs and needs no measurement: the ray tracer's compilation
# (numba's cache, by `simulate compile` in a process of its own: compiled inside the run, LLVM's memory came
# on top of the felt and its tables, the demo's peak), the start's two exit-table halves and felts (a Monte
# Carlo run of the start config with a few rays per incidence) and the structured walk of its surrogate (a
# summation fit of the start config with one evaluation, to that run's output: the walk depends on the
# wavelengths, not on the values), into the table cache; one thread each (the walk then holds one exit table
# at a time); their outputs and messages removed (shown when a step fails: exit status other than 0, or 3 for
# the fit's colour verdict). The fit finds them under the keys it looks up (a miss would only cost the time
# this saves), so neither its critical path nor its memory holds the compilation or the walk (its two entries
# at once, on an idle core, held ~1.4 GB of exit tables).
DEMO_COTTON = $(VENV)/bin/simulate fabric red-cotton --method summation --target-rel-err $(DEMO_REL_ERR) --no-progress --out $(DEMO_OUT)/red-cotton --force
DEMO_FIT_CLASSIC = $(VENV)/bin/simulate fit $(DEMO_CLASSIC_START) $(DEMO_OUT)/measured --method classic $(DEMO_DYE) --free $(DEMO_FREE) --max-evaluations $(DEMO_FIT_EVALS) --target-rel-err $(DEMO_FIT_REL_ERR) --no-progress --out $(DEMO_OUT)/fit-classic --force $(FIT_VERDICT)
DEMO_FIT_SUMMATION = $(VENV)/bin/simulate fit $(DEMO_START) $(DEMO_OUT)/measured --method summation $(DEMO_DYE) --free $(DEMO_FREE) --max-evaluations $(DEMO_FIT_EVALS) --target-rel-err $(DEMO_FIT_REL_ERR) --no-progress --out $(DEMO_OUT)/fit-summation --force $(FIT_VERDICT)
DEMO_MC_PREPARE = mkdir -p $(DEMO_OUT) && ( $(VENV)/bin/simulate compile $(DEMO_MC_START) --method mc --plan $(DEMO_MC_PREPARE_PLAN) && $(VENV)/bin/simulate fabric $(DEMO_MC_START) --method mc --plan $(DEMO_MC_PREPARE_PLAN) --target-rel-err $(DEMO_REL_ERR) --max-photons 64 --threads 1 --no-progress --out $(DEMO_OUT)/mc-prepare --force && ( $(VENV)/bin/simulate fit $(DEMO_MC_START) $(DEMO_OUT)/mc-prepare --method summation --free $(DEMO_MC_FREE) --max-evaluations 1 --target-rel-err $(DEMO_REL_ERR) --threads 1 --no-progress --out $(DEMO_OUT)/mc-prepare-walk --force $(FIT_VERDICT) ) ) >$(DEMO_OUT)/mc-prepare.log 2>&1 || ( cat $(DEMO_OUT)/mc-prepare.log >&2; false ); s=$$?; rm -rf $(DEMO_OUT)/mc-prepare $(DEMO_OUT)/mc-prepare-walk $(DEMO_OUT)/mc-prepare.log; [ $$s -eq 0 ]
DEMO_FIT_MC = $(VENV)/bin/simulate fit $(DEMO_MC_START) $(DEMO_OUT)/measured --method mc --free $(DEMO_MC_FREE) --max-runs $(DEMO_MC_RUNS) --target-rel-err $(DEMO_REL_ERR) --no-progress --out $(DEMO_OUT)/fit-mc --force $(FIT_VERDICT)
demo: $(BASE_STAMP)
	( $(DEMO_MC_PREPARE) ) & prepare=$$!; $(DEMO_COTTON) & beside=$$!; $(VENV)/bin/gonio demo --sample $(DEMO_SAMPLE) --plan $(DEMO_PLAN) --out $(DEMO_OUT)/measured --no-progress --force; s=$$?; wait $$beside && wait $$prepare && [ $$s -eq 0 ]
	$(VENV)/bin/gonio truth $(DEMO_SAMPLE) --plan $(DEMO_PLAN) --out $(DEMO_OUT)/truth --force
	$(VENV)/bin/compare check $(DEMO_OUT)/measured $(DEMO_OUT)/truth --max-nrmse 0.05
	( $(DEMO_FIT_MC) ) & beside=$$!; ( $(DEMO_FIT_CLASSIC) ) && ( $(DEMO_FIT_SUMMATION) ); s=$$?; wait $$beside && [ $$s -eq 0 ]
	$(VENV)/bin/compare report $(DEMO_OUT)/measured $(DEMO_OUT)/truth $(DEMO_OUT)/fit-classic/fitted $(DEMO_OUT)/fit-summation/fitted $(DEMO_OUT)/fit-mc/initial $(DEMO_OUT)/fit-mc/fitted --fit $(DEMO_OUT)/fit-classic --fit $(DEMO_OUT)/fit-summation --fit $(DEMO_OUT)/fit-mc --seed-sample $(DEMO_OUT)/red-cotton --out $(DEMO_OUT)/report --force
	@echo "demo: report in $(DEMO_OUT)/report/report.html"

# The headless browser of the browser tests (tests/docs/test_browser.py: the manual and a report;
# tests/gonio/cli/test_live_view.py: the live view): Debian's chromium, driven by Playwright through its
# executable path, installed with apt-get when missing (as root; sudo otherwise). No browser is
# downloaded by pip or Playwright. .ci/run runs this before `make test`.
browser:
	@if [ -x /usr/bin/chromium ]; then \
		echo "browser: $$(/usr/bin/chromium --version 2>/dev/null)"; \
	else \
		SUDO=$$([ "$$(id -u)" -eq 0 ] || echo sudo); \
		$$SUDO apt-get update && $$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y chromium; \
	fi

# three workers on two cores: many tests wait (on the mock instrument's replies, a browser, a child
# process), and a third worker runs while one waits; the kernels compile beside the first files (conftest.py)
test: $(STAMP) browser
	$(PY) -m pytest -q -n 3 --dist loadfile -m "not slow"

test-slow: $(STAMP) browser
	$(PY) -m pytest -q -n 2 --dist loadfile -m slow

# ruff and mypy, configured in pyproject.toml (versions pinned in the test extras); .ci/run runs it
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy

# The documentation site (docs/, mkdocs.yml) in strict mode: a broken link, a missing page or a
# docstring reference that does not resolve fails the build. Site in site/. `make test` builds it too
# (tests/docs/test_browser.py). `make reference` regenerates the command-line and config pages,
# `make figures` the tables of measured figures from docs/data/*.json.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --site-dir site

reference: $(STAMP)
	$(PY) docs/scripts/gen_reference.py

figures: $(STAMP)
	$(PY) docs/scripts/render_figures.py

# docs/architecture.md's module map against the code: prints the modules without a line and the lines
# without a module, adds a line for each new module (its docstring's first sentence, to be edited) and
# removes the lines of removed ones (tests/docs/test_architecture.py fails until the page is mended)
architecture:
	$(PYTHON) docs/scripts/architecture.py

bench: $(STAMP)
	$(VENV)/bin/simulate bench --out bench-out
	$(VENV)/bin/gonio bench-driver --plan red-cotton --out bench-out/driver.json

clean:
	rm -rf $(VENV) $(DEMO_OUT) bench-out .pytest_cache site
