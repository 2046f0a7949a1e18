# Two commands on a fresh machine: `make demo` and `make test`. Everything else is optional.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
DEMO := out/demo
DEMO_DESIGN := flat_roof=flat-membrane-white-tpo,sloped_roof=sloped-clay-terracotta

.PHONY: setup demo test test-all bench-render clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

setup: $(STAMP)

# The main job on its embedded defaults: build the texture bank, render a 3x3-tile city with one design.
demo: setup
	$(BIN)/meta-sim textures build
	$(BIN)/meta-sim textures sheet --out $(DEMO)/texture-bank.png
	$(BIN)/meta-sim render --design $(DEMO_DESIGN) --seed 1 --tiles 9 --preset fast --out $(DEMO) --preview
	@echo "Tiles, previews and the city mosaic are in $(DEMO)/"

# The fast default set plus one real end-to-end run (slow-marked tests run in `test-all`).
test: setup
	$(BIN)/python -m pytest -q

test-all: setup
	$(BIN)/python -m pytest -q -m ''

bench-render: setup
	$(BIN)/meta-sim bench render --out benchmarks/render.json

clean:
	rm -rf out build dist *.egg-info
