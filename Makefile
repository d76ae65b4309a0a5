# The two commands the README opens with:
#   make demo   build .venv and run the main job on the bundled demo flight (out/demo/)
#   make test   build .venv and run the whole test suite
PYTHON ?= python3
VENV   := .venv
STAMP  := $(VENV)/.installed

.PHONY: demo test venv bench clean demo-bag

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
	$(VENV)/bin/python -m pytest -q -ra

# Regenerate the bundled demo bag (command recorded in bags/README.md).
demo-bag: $(STAMP)
	rm -rf bags/demo
	$(VENV)/bin/srmosaic simulate --world data/worlds/caliterra_IMG_9360.jpg --trajectory line \
	    --frames 60 --width 640 --height 480 --transport compressed --storage sqlite3 --seed 7 --out bags/demo

clean:
	rm -rf $(VENV) out build *.egg-info
