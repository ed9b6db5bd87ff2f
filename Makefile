# The two commands the README shows: `make demo` and `make test`.
# Both run the idempotent set-up first (LLVM 19, .venv/, the tree library).

.PHONY: setup demo test lint bench openapi

setup:
	@bash scripts/setup.sh

demo: setup
	.venv/bin/forest scatter configs/demo.toml -o out/demo_trees.npz
	.venv/bin/forest render configs/demo.toml --instances out/demo_trees.npz -o out/demo.exr

# Conventions CI enforces before the tests: ruff (lint + format) and mypy (forest/ and service/; strict on the hub,
# forest.render and forest.lookdev).
lint: setup
	.venv/bin/ruff check .
	.venv/bin/ruff format --check .
	.venv/bin/mypy

# Two workers (pytest-xdist): 8.5 min instead of 12 on the 2-core CI machine; the slowest tests are printed.
test: setup
	.venv/bin/python -m pytest -q -p no:cacheprovider -n 2 --durations=15 tests

bench: setup
	.venv/bin/python bench/run_all.py

# The job service's OpenAPI document, docs/openapi.json (tests/test_docs.py fails while it is stale).
openapi: setup
	.venv/bin/python scripts/make_openapi.py
