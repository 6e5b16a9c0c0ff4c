# The quick start: `make demo` and `make test`. Both install first (idempotently).
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
SYSTEM_LIBS := libusb-1.0-0

.PHONY: install demo test test-fast bench lint clean

install: $(STAMP)

$(STAMP): pyproject.toml
	@missing=""; for lib in $(SYSTEM_LIBS); do \
	  dpkg -s $$lib >/dev/null 2>&1 || missing="$$missing $$lib"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ]; then \
	    echo "installing system libraries:$$missing"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	  else \
	    echo "missing system libraries:$$missing (run: sudo apt-get install -y$$missing)"; exit 1; \
	  fi; \
	fi
	@test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	@# setuptools' notice that an editable install is one (a UserWarning re-raised by pip) is
	@# the only output left; the layout it warns about is deliberate (tests/test_packaging.py).
	PYTHONWARNINGS="ignore:Editable installation:UserWarning" $(PY) -m pip install -q -e ".[dev]"
	@touch $(STAMP)

demo: install
	$(VENV)/bin/tcaff demo

test: install
	$(VENV)/bin/pytest -q

# the quick subset for development: everything but the end-to-end runs marked `slow`
test-fast: install
	$(VENV)/bin/pytest -q -m "not slow"

bench: install
	$(PY) scripts/bench_startup.py
	$(PY) scripts/bench_association.py
	$(PY) scripts/bench_tcaff.py
	$(PY) scripts/bench_graph.py
	$(PY) scripts/bench_study.py
	$(PY) scripts/bench_mapping.py
	$(PY) scripts/bench_mot.py
	$(PY) scripts/bench_results_io.py

lint: install
	$(VENV)/bin/ruff check .

clean:
	rm -rf $(VENV) build dist *.egg-info
