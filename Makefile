# make demo: the shipped CIC walker snapshot fine-tuned on walker flip beside DDPG from scratch; prints both
#            scores, writes the learning curves and a skill video to demo_output/ (CPU, a few minutes)
# make test: the test suite
# Both create the virtual environment .venv and install the project into it on first use.
VENV ?= .venv
PY := $(VENV)/bin/python
# the tests need no rendering (the video tests set MUJOCO_GL=egl themselves); the demo renders its skill
# video with the headless backend that sb3_cic finds when MUJOCO_GL is unset
test: export MUJOCO_GL ?= disable

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
