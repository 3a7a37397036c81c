# Every target sets itself up from nothing: a fresh clone needs only python3.11.
VENV := .venv
PY := $(VENV)/bin/python
INSTALLED := $(VENV)/.installed
# The serving install lives apart: it must never contain torch.
SERVE_VENV := .venv-serve
SERVE_INSTALLED := $(SERVE_VENV)/.installed

.PHONY: install test test-quick lint serve openapi system-packages

$(INSTALLED): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch first and exactly: this version has a CPU build here; anything looser pulls CUDA wheels.
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[train,ros,dev]'
	touch $@

$(SERVE_INSTALLED): pyproject.toml
	python3 -m venv $(SERVE_VENV)
	$(SERVE_VENV)/bin/python -m pip install -q --upgrade pip
	$(SERVE_VENV)/bin/python -m pip install -q -e .
	touch $@

install: $(INSTALLED)

lint: $(INSTALLED)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

# The tests drive Debian's chromium (the web page) and nginx (the load balancer), build and run the image with
# podman (runc runs it; debootstrap builds the stand-in for python:3.11-slim), build a ROS 2 subscriber on
# Cyclone DDS's C library (cyclonedds-dev, its idlc in cyclonedds-tools) and read RTPS with tshark; installing
# them needs root.
SYSTEM_PACKAGES := chromium nginx-light podman runc debootstrap cyclonedds-dev cyclonedds-tools tshark
system-packages:
	@command -v chromium >/dev/null && command -v nginx >/dev/null && command -v podman >/dev/null && \
	    command -v runc >/dev/null && command -v debootstrap >/dev/null && command -v idlc >/dev/null && \
	    test -f /usr/include/dds/dds.h && command -v tshark >/dev/null || \
	    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(SYSTEM_PACKAGES); } || \
	    { echo "make test needs $(SYSTEM_PACKAGES): apt-get install them as root"; exit 1; }

test: lint system-packages
	$(PY) -m pytest

# The quick tier while developing (under two minutes): no fits, trainings, clusters or browsers.
test-quick: lint system-packages
	$(PY) -m pytest -m "not slow"

# The service on 127.0.0.1:8000 with the bundled default model (weights/), and the models fit published
# (RGB2CLOUD_REGISTRY, default ~/.local/share/rgb2cloud/models) beside it; RGB2CLOUD_* overrides.
serve: $(SERVE_INSTALLED)
	$(SERVE_VENV)/bin/python -m app

openapi: $(INSTALLED)
	$(PY) -m app.openapi
