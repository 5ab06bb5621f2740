# make demo: a small CIC pre-training + fine-tuning on walker flip, prints the score (CPU, minutes)
# make test: the test suite
# Both create the virtual environment .venv and install the project into it on first use.
VENV ?= .venv
PY := $(VENV)/bin/python
export MUJOCO_GL ?= disable

.PHONY: demo test install clean

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

clean:
	rm -rf $(VENV) *.egg-info .pytest_cache
