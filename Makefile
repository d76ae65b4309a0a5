# The two commands the README opens with:
#   make demo   build .venv and run the main job on the bundled demo flight (out/demo/)
#   make test   build .venv, lint the repository (ruff.toml), build the docs and run the whole test suite
# Also: make docs (the documentation site into site/), make reference (regenerate docs/reference/).
PYTHON ?= python3
VENV   := .venv
STAMP  := $(VENV)/.installed
# pytest-xdist workers of make test: three on the 2-core machines it is sized for, because the live
# tests wait on DDS much of their time; each test file runs whole on one worker, so a module's
# shared fixtures are built once; the files start longest first (test/suite_order.py), not xdist's most-tests-first
TEST_WORKERS ?= 3
# OpenMP (torch) threads per test process: the workers already fill the cores, and more threads than
# cores spin-wait for each other
TEST_THREADS ?= 1

.PHONY: demo test venv bench clean demo-bag docs reference

venv: $(STAMP)

$(STAMP): setup.py setup.cfg package.xml
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --upgrade pip
	$(VENV)/bin/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/srmosaic process bags/demo --out out/demo
	$(VENV)/bin/srmosaic evaluate out/demo --truth bags/demo/ground_truth.json

test: $(STAMP)
	$(VENV)/bin/ruff check .
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet --site-dir site
	OMP_NUM_THREADS=$(TEST_THREADS) $(VENV)/bin/python -m pytest -q -ra --durations=20 -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

# The documentation site (mkdocs.yml, docs/) into site/; --strict: a broken link or a missing page fails it.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --site-dir site

# docs/reference/{parameters,nodes,cli}.md from params/*.yaml, the nodes and the CLI (test/test_docs.py
# fails when the committed pages differ from what this writes).
reference: $(STAMP)
	$(VENV)/bin/python -m srmosaic_ros.docs_reference

# Regenerate the bundled demo bag (command recorded in bags/README.md).
demo-bag: $(STAMP)
	rm -rf bags/demo
	$(VENV)/bin/srmosaic simulate --world data/worlds/caliterra_IMG_9360.jpg --trajectory line \
	    --frames 60 --width 640 --height 480 --transport compressed --storage sqlite3 --seed 7 --out bags/demo

# SR demonstration: a raw 320x240 flight seeing 0.36 m per pixel of the 0.1 m/px world, simulated
# on the fly (about 5 s; as a bundled raw bag it would be 7 MB), then process --sr and evaluate,
# which prints the SR figures against the true ground and writes out/demo-sr/sr/compare.png.
.PHONY: demo-sr
demo-sr: $(STAMP)
	$(VENV)/bin/srmosaic simulate --trajectory line --frames 40 --width 320 --height 240 --heading 90 \
	    --start -130 -105 --transport raw --seed 11 --no-progress --overwrite --out out/demo-sr-bag
	$(VENV)/bin/srmosaic process out/demo-sr-bag --out out/demo-sr --sr --params bags/sr_demo/params.yaml
	$(VENV)/bin/srmosaic evaluate out/demo-sr --truth out/demo-sr-bag/ground_truth.json

clean:
	rm -rf $(VENV) out build site *.egg-info
