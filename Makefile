# rths: the two commands a user needs are `make demo` and `make test`.
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
.DEFAULT_GOAL := help

help:  ## list the targets
	@grep -E '^[a-z-]+:.*##' $(MAKEFILE_LIST) | sed 's/:.*## /\t/'

setup:  ## create .venv, install pinned ROS 2 Jazzy + deps, repair paths, colcon build (idempotent)
	@tools/setup.sh

demo: setup  ## run the main job (rths run: identify, design, RTHS of the building, review)
	@source env.sh && rths run

# make test installs OpenSeesPy (setup-opensees) so that its tests run; OPENSEES=no leaves it
# out (its licence: README, 'OpenSeesPy'): those tests then skip, or fail under CI=true.
TEST_NEEDS := setup $(if $(filter no,$(OPENSEES)),,setup-opensees)

test: $(TEST_NEEDS)  ## build and run every test through colcon test (installs OpenSeesPy unless OPENSEES=no); non-zero on any failure
	@tools/run_tests.sh

docs: setup  ## regenerate docs/cli.md and docs/benchmarks.md (from argparse), docs/performance.md (from docs/bench/*.json), the packages' module tables
	@source env.sh && python -m rths_bench.refdocs --write

fuzz: setup  ## the long fuzz campaign: FUZZ_EXAMPLES (10000) cases per parser; counts to docs/fuzz.json
	@source env.sh && rm -f docs/fuzz.json && RTHS_FUZZ_EXAMPLES=$${FUZZ_EXAMPLES:-10000} \
	  RTHS_FUZZ_REPORT=$(CURDIR)/docs/fuzz.json nice -n 10 python -m pytest -q -p no:cacheprovider \
	  test/test_fuzz_inputs.py src/rths_bringup/test/test_cli_validation.py && \
	  echo "make fuzz: counts in docs/fuzz.json"

lint: setup  ## ruff and flake8 over src/ and test/ (ruff.toml, ament_lint.ini), mypy on rths_common and the step cores (mypy.ini)
	@source env.sh && ruff check src test && flake8 --config ament_lint.ini src test && \
	  mypy --config-file mypy.ini -p rths_common -p rths_numerical.substructure \
	    -p rths_compensator.filters -p rths_compensator.core -p rths_numerical.stepping \
	    -p rths_actuator_bridge.bridge && \
	  echo "make lint: clean"

setup-opensees: setup  ## install OpenSeesPy (backend: opensees; not open source for commercial use); make test does it
	@if .venv/bin/python -c 'import importlib.metadata as m, sys; v = [l.split("==")[1].split(";")[0].strip() for l in open("constraints.txt") if l.startswith("openseespy==")]; sys.exit(0 if v and m.version("openseespy") == v[0] else 1)' 2>/dev/null; then \
	  echo "[setup-opensees] openseespy up to date"; \
	else \
	  echo "[setup-opensees] installing openseespy (constraints.txt; licence: see README, 'OpenSeesPy'; OPENSEES=no for make test without it)"; \
	  .venv/bin/python -m pip install --quiet --disable-pip-version-check -c constraints.txt openseespy 2>&1 | grep -v "^WARNING: Location" || true; \
	fi; \
	  source env.sh && python -c 'from rths_numerical.opensees_backend import opensees_available as a; ok, v = a(); print("[setup-opensees]", "openseespy", v if ok else "FAILED: " + v); raise SystemExit(0 if ok else 1)'

clean:  ## remove build products (keeps .venv)
	rm -rf build install log

distclean: clean  ## remove build products and the venv
	rm -rf .venv

.PHONY: help setup setup-opensees demo test docs fuzz lint clean distclean
