# equipose — set-up and entry points. A fresh machine needs only Python 3.11.
PYTHON ?= python3
VENV ?= .venv
DEMO_VENV ?= .venv-demo
PIP_FLAGS ?= -q --disable-pip-version-check

.PHONY: demo test venv demo-venv clean

# Main job on the bundled sample, with the runtime only (no torch).
demo: $(DEMO_VENV)/.installed
	$(DEMO_VENV)/bin/equipose demo

$(DEMO_VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(DEMO_VENV)
	$(DEMO_VENV)/bin/pip install $(PIP_FLAGS) --upgrade pip
	$(DEMO_VENV)/bin/pip install $(PIP_FLAGS) .
	touch $@

# Full development environment: torch==2.13.0 first (CPU wheel), then the package with all extras.
venv: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install $(PIP_FLAGS) --upgrade pip
	$(VENV)/bin/pip install $(PIP_FLAGS) torch==2.13.0
	$(VENV)/bin/pip install $(PIP_FLAGS) -e '.[train,camera,dev]'
	touch $@

test: $(VENV)/.installed
	DEPTHAI_LEVEL=error $(VENV)/bin/python -m pytest -q

clean:
	rm -rf $(VENV) $(DEMO_VENV) build *.egg-info runs
