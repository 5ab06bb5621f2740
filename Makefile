# make demo: the shipped CIC quadruped snapshot fine-tuned on quadruped jump beside DDPG from scratch; prints
#            both scores, writes the learning curves and a skill video to demo_output/ (CPU)
# make test: the test suite
# make docs: the documentation site (Sphinx, warnings as errors) into docs/_build/html
# Each creates the virtual environment .venv and installs the project into it on first use.
VENV ?= .venv
PY := $(VENV)/bin/python
# the tests need no rendering (the video tests set MUJOCO_GL=egl themselves); the demo renders its skill
# video with the headless backend that sb3_cic finds when MUJOCO_GL is unset
test: export MUJOCO_GL ?= disable

.PHONY: demo test docs install clean

install: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml setup.cfg
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test]"
	touch $@

demo: install
	$(PY) -m sb3_cic.demo

test: install
	$(PY) -m pytest

# the docs extra (Sphinx, MyST, the Read the Docs theme) into the same .venv, on first use
$(VENV)/.docs-installed: $(VENV)/.installed
	$(PY) -m pip install --quiet -e ".[docs]"
	touch $@

# every page is read anew each time (-E: a warning of an unchanged page is not hidden by an incremental
# build), and the API pages are generated anew, so that a moved or removed module leaves no page behind
docs: $(VENV)/.docs-installed
	rm -rf docs/api/_generated
	$(PY) -m sphinx -E -W --keep-going -b html docs docs/_build/html

clean:
	rm -rf $(VENV) *.egg-info .pytest_cache docs/_build docs/api/_generated
