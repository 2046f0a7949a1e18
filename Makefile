# Two commands on a fresh machine: `make demo` and `make test`. Everything else is optional.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
DEMO := out/demo
DEMO_DESIGN := flat_roof=flat-membrane-white-tpo,sloped_roof=sloped-clay-terracotta
DEMO_HIDDEN := flat_roof=flat-gravel-dark,sloped_roof=sloped-seam-green
DEMO_TARGETS := 12
DEMO_STARTS := 64
DEMO_ITERATIONS := 100

.PHONY: setup demo test test-all lint addon bench-render bench-exposure bench-nams bench-adjoint bench-ablations bench-tradeoff bench-farm bench-reference bench-infer bench-task bench-realism bench-appearance bench-stability bench-roof-finder bench-objective bench-sensor clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[all,test]'
	touch $(STAMP)

setup: $(STAMP)

# The main job on its embedded defaults: build the texture bank, render a training set, train NAMS and the
# DR baseline, run E1 (without the sbi baseline, to keep within the demo's 15 minutes; bench-nams scores it),
# then infer the design of a target city rendered with a design the model is not told. Nothing runs beside it, so
# the torch side uses every CPU (META_SIM_THREADS; by default it leaves one free), and its E1 runs the adjoint
# search at the continuous spaces' default (64 starts x 100 steps, not the paper's 1000 x 200: bench-nams has both).
demo: export META_SIM_THREADS ?= $(shell nproc 2>/dev/null || echo 2)
demo: setup
	$(BIN)/meta-sim textures build
	$(BIN)/meta-sim textures sheet --out $(DEMO)/texture-bank.png
	$(BIN)/meta-sim render --design $(DEMO_DESIGN) --seed 1 --tiles 9 --preset fast --out $(DEMO)/city --preview
	$(BIN)/meta-sim eval e1 --out $(DEMO)/e1 --no-sbi --targets $(DEMO_TARGETS) -M $(DEMO_STARTS) --iterations $(DEMO_ITERATIONS)
	$(BIN)/meta-sim render --design $(DEMO_HIDDEN) --seed 4242 --tiles 9 --preset fast --out $(DEMO)/target
	$(BIN)/meta-sim infer $(DEMO)/target --model $(DEMO)/e1/nams.pt --out $(DEMO)/infer --overwrite
	@echo "The hidden design was $(DEMO_HIDDEN)"
	@cat $(DEMO)/e1/results.md
	@echo "Look at $(DEMO)/city/*_mosaic.png, $(DEMO)/e1/sheet.png and $(DEMO)/infer/report.png"

# The fast default set plus one real end-to-end run (slow-marked tests run in `test-all`). The add-on's tests
# run in a process of their own, as Blender runs the add-on: without torch, which the other tests load.
test: setup
	$(BIN)/python -m pytest -q tests/addon
	$(BIN)/python -m pytest -q --ignore=tests/addon

# ruff (style, pyflakes, isort, bugbear) and import-linter (the layer rule in pyproject.toml).
lint: setup
	$(BIN)/ruff check .
	$(BIN)/lint-imports

test-all: setup
	$(BIN)/python -m pytest -q -m '' tests/addon
	$(BIN)/python -m pytest -q -m '' --ignore=tests/addon

# The Blender extension zip (Blender's own validator and builder, from the bpy wheel): dist/meta_sim-0.1.0.zip
addon: setup
	$(BIN)/python jobs/build_addon.py --out dist

bench-render: setup
	$(BIN)/meta-sim bench render --out benchmarks/render.json

# The fast preset's exposure (quality.FAST_EXPOSURE): flat roofs' brightness, path traced over rasterised, on the
# training set's first 100 designs x 2 tiles (about 3 minutes on 2 CPUs).
bench-exposure: setup
	$(BIN)/meta-sim bench exposure --out benchmarks/exposure.json

# Every knob that costs time against E1 accuracy, and the fast/balanced/paper profiles (long: the paper
# profile renders 15,300 tiles). Reads benchmarks/render.json (render cost), benchmarks/nams.json (the search
# methods' rows), benchmarks/adjoint.json (the adjoint's settings) and benchmarks/ablations.json (the variants'):
# run bench-render, bench-nams, bench-adjoint and bench-ablations first. The paper profile's adjoint search runs on
# 10 target groups per split, as bench-adjoint's (about a minute per group on 2 CPUs). Longer than a working
# session on 2 CPUs: measure it in parts, each merged into the last (the weights of a training set trained again
# are checked to be the same), e.g.
#   make bench-tradeoff TRADEOFF_ARGS="--training-sets 150x4,300x2,300x4,600x2,600x4 --presets fast --profiles fast,balanced"
#   make bench-tradeoff TRADEOFF_ARGS="--merge --training-sets '' --presets balanced --profiles ''"
#   make bench-tradeoff TRADEOFF_ARGS="--merge --training-sets 1700x9 --presets '' --profiles paper"
TRADEOFF_ARGS ?=
bench-tradeoff: setup
	$(BIN)/meta-sim bench tradeoff --adjoint-targets 10 --out benchmarks/tradeoff.json --plot benchmarks/tradeoff.png $(TRADEOFF_ARGS)

bench-farm: setup
	$(BIN)/meta-sim bench farm --out benchmarks/farm.json

# Peak memory and throughput of `meta-sim infer` on 180, 1,440 and 11,520 real tiles (links to
# ../shared/realdata) and one 16,000 x 16,000 px image; trains the default model first if it is not cached.
bench-infer: setup
	$(BIN)/meta-sim bench infer --out benchmarks/infer.json

# The paper's task-model experiments (E1, E2, E3 and the sim-only transfer): a building segmenter per
# augmentation strategy and seed, scored on the targets' test tiles (about an hour on 2 CPUs once the
# default model is cached; both CPUs train).
bench-task: setup
	META_SIM_THREADS=2 $(BIN)/meta-sim bench task --out benchmarks/task.json --pictures benchmarks/task

# E1 in the overhead-v1 design space: how well NAMS infers a target's ground, vegetation, sun, brightness, sensor
# and city style besides its roofs (trains its own model on 1,200 designs first; its cache serves bench-realism).
bench-appearance: setup
	META_SIM_THREADS=2 $(BIN)/meta-sim bench appearance --out benchmarks/appearance.json --pictures benchmarks/appearance

# How close renders are to each real domain (`meta-sim bench realism --runs overhead-v1` remeasures one run and
# keeps the other rows; `--tables` rewrites the tables from the JSON) (sim-only building IoU and a real-vs-rendered
# classifier);
# shares bench-task's cache of trained segmenters.
bench-realism: setup
	META_SIM_THREADS=2 $(BIN)/meta-sim bench realism --out benchmarks/realism.json --pictures out/bench-pictures/realism

# E1 and E2 on the test split (300 target groups each, 95% intervals) with the validation split beside it, every
# method (the adjoint search at 64 starts x 100 steps; its other settings are bench-adjoint's).
bench-nams: setup
	$(BIN)/meta-sim bench nams --out benchmarks/nams.json

# The neural-adjoint search from the paper's setting (1000 starts x 200 steps) down, on 10 of bench-nams' target
# groups per split and experiment: about an hour on 2 CPUs (at the paper's setting the 10 groups of a split take
# some 9 minutes; 20 groups, the command's default, take three times as long, as 16,384 starts share a step).
bench-adjoint: setup
	$(BIN)/meta-sim bench adjoint --adjoint-targets 10 --out benchmarks/adjoint.json

# The default model beside its variants (the other NAMS architectures, the roof-colour ablations), each trained on
# the same training set, on bench-nams' targets (long on an empty cache: six models to train, two feature sets).
bench-ablations: setup
	$(BIN)/meta-sim bench ablations --out benchmarks/ablations.json

# Each training set's roof finder on the real domains' labelled scenes (rooftops-v1's and overhead-v2's; learns
# what the cache lacks): roof pixels it counts against the building masks and the training cities' range.
bench-roof-finder: setup
	META_SIM_THREADS=2 $(BIN)/meta-sim bench roof-finder --finders segmenter,segmenter-jitter --out benchmarks/roof_finder.json

# Each named sensor's sharpness against the fine detail of the real domains' adapt scenes it stands for
# (renders 48 tiles once, then seconds).
bench-sensor: setup
	$(BIN)/meta-sim bench sensor --out benchmarks/sensor.json

# What each extreme case (constant, black, white, HDR and NaN targets; one-tile groups; M=1, S=M, k=0, r=0 and 1;
# a one-choice space; zero-variance features; bfloat16) ends in, on tiny models made in the run (a few minutes).
bench-stability: setup
	$(BIN)/meta-sim bench stability --out benchmarks/stability.json

# How far the renders' roof colours (found with the roof labels) agree with the swatch similarity that
# scores E1/E2: a reference for bench-nams' accuracy, on the same training set and targets.
bench-reference: setup
	$(BIN)/meta-sim bench reference --out benchmarks/reference.json

# How the search compares the roof-colour histograms (exponent, blur over neighbouring colours): a grid on the
# validation split of E1 and E2, the best chosen there, the default and the chosen one on test (minutes once
# bench-nams' model and targets are cached).
bench-objective: setup
	$(BIN)/meta-sim bench objective --out benchmarks/objective.json

clean:
	rm -rf out build dist *.egg-info
