# drake_att: two commands do all set-up on a fresh machine.
#   make run    run the default scenario (creates .venv and installs what is missing)
#   make test   lint and format check (ruff), type-check (mypy), then the test suite (same set-up)
# and, with the same set-up:
#   make docs   build the documentation site into site/ (offline; open site/index.html)
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: run test docs bench mutation clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test]"
# cedar-solve, the reference solver of diagrams/sky_identification.py: its metadata pins
# numpy<2 and Pillow<9, which its code does not need (numpy 2 works; it reads no image here)
	$(PY) -m pip install --quiet --no-deps "cedar-solve==0.5.1"
	@command -v dot >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq && apt-get install -y -qq graphviz >/dev/null) || \
	  echo "note: Graphviz 'dot' not installed; diagram.svg will be skipped (diagram.dot is always written)"; }
	@command -v chromium >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) || \
	  echo "note: Chromium not installed; the Monte Carlo report's headless-browser test will be skipped"; }
	@touch $(STAMP)

run: $(STAMP)
	$(VENV)/bin/drake-att run $(ARGS)

# Lint, format check and type check first ([tool.ruff], [tool.mypy] in pyproject.toml), then the suite.
test: $(STAMP)
	$(PY) -m ruff check drake_att benchmarks diagrams tests
	$(PY) -m ruff format --check drake_att benchmarks diagrams tests
	$(PY) -m mypy drake_att/contract.py drake_att/filters drake_att/systems drake_att/scenarios
	MPLBACKEND=Agg $(PY) -m pytest -q $(PYTEST_ARGS)

# Mutation testing of the math and filter-core modules, each against its own unit tests (not
# part of `make test`; all ~5000 mutants take ~2 h on 2 cores: MUTATION_ARGS="--sample 120"
# runs a seeded sample per module in ~30 min). Figures and equivalents: tests/README.md.
MUTATION_ARGS ?=
mutation: $(STAMP)
	$(PY) -m pip install --quiet "mutmut==3.8.1"
	$(PY) tests/mutation_run.py $(MUTATION_ARGS)
	$(PY) tests/mutation_report.py

# The documentation site (mkdocs.yml; docs/developer/docs.md), strict: a warning fails the build.
# The notebooks run during the build, shortened (DRAKE_ATT_NOTEBOOK_TEST=1: ~1.5 min on 2 cores),
# so the Tutorials pages show their outputs; the strict-build test renders them without running.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 DRAKE_ATT_DOCS_EXECUTE=true DRAKE_ATT_NOTEBOOK_TEST=1 MPLBACKEND=Agg \
	  $(PY) -m mkdocs build --strict --site-dir site

bench: $(STAMP)
	$(PY) benchmarks/bench_scenarios.py

clean:
	rm -rf $(VENV) out .pytest_cache mutants /tmp/drake_att_mutation
