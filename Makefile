# Two commands set everything up: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
DEMO_DB := demo/demo.duckdb

.PHONY: venv demo test bench docs clean

$(BIN)/logiq-sql: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	@touch $@

venv: $(BIN)/logiq-sql

demo: venv
	rm -f $(DEMO_DB)
	$(BIN)/logiq-sql ingest commonroad tests/data/commonroad_ngsim --db $(DEMO_DB)
	$(BIN)/logiq-sql ingest scenarionet tests/data/nuscenes_mini_scenarionet --db $(DEMO_DB)
	$(BIN)/logiq-sql match --db $(DEMO_DB) --out demo/out

test: venv
	$(BIN)/python -m pytest -q

bench: venv
	$(BIN)/python -m benchmarks.spine $(BENCH_ARGS)

docs: venv
	$(BIN)/python -c "from logiq_sql.db import docs_markdown; print(docs_markdown())" > docs/tables.md

clean:
	rm -rf $(VENV) demo build dist .pytest_cache
