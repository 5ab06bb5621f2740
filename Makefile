# make demo: the shipped CIC quadruped snapshot fine-tuned on quadruped jump beside DDPG from scratch; prints
#            both scores, writes the learning curves and a skill video to demo_output/ (CPU)
# make test: the test suite
# make test-quick: a first check of a few minutes (the environments, every method's construction and update, the
#                  command line's refusals, the package's structure)
# make docs: the documentation site (Sphinx, warnings as errors) into docs/_build/html
# Each creates the virtual environment .venv and installs the project into it on first use.
VENV ?= .venv
QUICK_TESTS := tests/test_structure.py tests/test_help.py tests/test_envs.py tests/test_methods.py tests/test_cli_errors.py
PY := $(VENV)/bin/python
# the tests need no rendering (the video tests set MUJOCO_GL=egl themselves); the demo renders its skill
# video with the headless backend that sb3_cic finds when MUJOCO_GL is unset
test: export MUJOCO_GL ?= disable

.PHONY: demo test test-quick docs install clean

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

test-quick: export MUJOCO_GL ?= disable
test-quick: install
	$(PY) -m pytest -m "not slow" $(QUICK_TESTS)

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
