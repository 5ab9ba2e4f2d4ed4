# The two commands of the README: `make eval` (main job) and `make test`. Both set up .venv first.
VENV := .venv
PY := $(VENV)/bin/python
export MUJOCO_GL ?= egl
# Material for MkDocs prints a banner about MkDocs 2 on every build
export NO_MKDOCS_2_WARNING ?= 1

.PHONY: setup eval test test-slow bench lint docs

$(VENV)/.installed: pyproject.toml scripts/setup.sh
	bash scripts/setup.sh

setup: $(VENV)/.installed

eval: $(VENV)/.installed
	$(PY) -m eval

test: $(VENV)/.installed
	$(PY) -m pytest -n auto --dist loadfile --no-loadscope-reorder

test-slow: $(VENV)/.installed
	$(PY) -m pytest -n auto --dist loadfile --no-loadscope-reorder -m slow

bench: $(VENV)/.installed
	$(PY) scripts/bench.py

lint: $(VENV)/.installed
	$(VENV)/bin/ruff check . && $(VENV)/bin/ruff format --check .

# The documentation site, warnings as errors, into site/ (git-ignored)
docs: $(VENV)/.installed
	$(VENV)/bin/mkdocs build --strict
