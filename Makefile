# The two commands of the README: `make demo` and `make test`. Both create or reuse .venv.
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test lint bench bootstrap clean

bootstrap:
	@VENV=$(VENV) EXTRAS=train scripts/bootstrap.sh

demo: bootstrap
	$(BIN)/gprbot demo --out runs/demo

test: bootstrap
	$(BIN)/ruff check gprbot tests benchmarks tools training validation
	$(BIN)/mypy
	$(BIN)/pytest

bench: bootstrap
	$(BIN)/python -m benchmarks.run_all

clean:
	rm -rf runs .pytest_cache .mypy_cache .ruff_cache
