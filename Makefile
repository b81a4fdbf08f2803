# One-command setup and run on a fresh Debian machine with Python 3.11.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-$(shell cat pyproject.toml | sha1sum | cut -c1-12)
CONFIG ?= config/placecell.toml

.PHONY: run test test-under-load lint typecheck pytest bench clean zenohd

$(STAMP): pyproject.toml
	@tools/setup-system.sh venv
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	@rm -f $(VENV)/.installed-*
	@touch $@

run: $(STAMP)
	$(BIN)/placecelld --config $(CONFIG)

test: $(STAMP)
	@tools/setup-system.sh test
	@tools/build-zenohd.sh >/dev/null
	$(MAKE) lint typecheck pytest

# The suite with two busy-loop processes beside it, as on a robot's loaded computer.
test-under-load: $(STAMP)
	tools/under-load.sh -n 2 $(MAKE) test

lint: $(STAMP)
	$(BIN)/ruff check kernel daemon hal tools tests
	$(BIN)/lint-imports

typecheck: $(STAMP)
	$(BIN)/mypy

pytest: $(STAMP)
	$(BIN)/pytest -q -n 2 --dist loadgroup

# zenoh's router and its storage manager plugin at the binding's version, built once per
# machine (tools/build-zenohd.sh).
zenohd: $(STAMP)
	tools/build-zenohd.sh

bench: $(STAMP)
	$(BIN)/placecell-bench --json

clean:
	rm -rf $(VENV) var .pytest_cache .mypy_cache .ruff_cache
