# The quick start: `make demo` and `make test`. Both install first (idempotently).
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# iproute2: `ip`, which brings up the loopback of the network namespaces the ROS 2 (DDS) tests run
# in (unshare, of util-linux, makes them)
SYSTEM_LIBS := libusb-1.0-0 iproute2 util-linux
# Python's byte code and pytest's rewritten test modules are cached in __pycache__ (ignored by
# git) even where the environment asks for none: without them every test worker and every
# `tcaff` process the tests start compiles the sources again (7 s more of collection per worker)
unexport PYTHONDONTWRITEBYTECODE

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
	@# -qq: pip's errors only. Its warnings are a line for every package that a configured
	@# local index lacks (278 lines on the build machines), none of them about this project.
	$(PY) -m pip install -qq --upgrade pip
	@# setuptools' notice that an editable install is one (a UserWarning re-raised by pip)
	@# would be the only output left; the layout it warns about is deliberate
	@# (tests/test_packaging.py).
	PYTHONWARNINGS="ignore:Editable installation:UserWarning" $(PY) -m pip install -qq -e ".[dev]"
	@# numba compiles the package's kernels (alignment, people tracker, mapping) once, here, into
	@# the cache next to the package, so that no process pays seconds of compilation on its first
	@# step
	$(PY) -m tcaff_gtsam.eval.precompile
	@touch $(STAMP)

demo: install
	$(VENV)/bin/tcaff demo

# every test, spread over the machine's cores (worksteal: an idle worker takes queued tests
# from a busy one, so the long end-to-end tests do not end up queued behind each other). The
# live nodes that must keep up with the clock (`realtime`) run beside them: they need the CPU
# for moments only, and get it first because the others run at a lower priority (nice); their
# report follows the others'. Both parts always run; make fails if either does; Ctrl-C stops
# both.
test: install
	@status=0; live=$$(mktemp); \
	$(VENV)/bin/pytest -q -p no:cacheprovider -m realtime tests/node >"$$live" 2>&1 & nodes=$$!; \
	trap 'kill $$nodes 2>/dev/null; rm -f "$$live"' EXIT; trap 'exit 130' INT TERM; \
	nice -n 10 $(VENV)/bin/pytest -q -n auto --dist worksteal -m "not realtime" || status=$$?; \
	wait $$nodes || status=$$?; \
	echo "live nodes (realtime):"; cat "$$live"; \
	exit $$status

# the quick subset for development: everything but the end-to-end runs marked `slow`
test-fast: install
	$(VENV)/bin/pytest -q -m "not slow"

BENCH_SCRIPTS := bench_startup bench_association bench_tcaff bench_graph bench_team bench_scale \
	bench_study bench_mapping bench_mot bench_results_io bench_image_files
BENCH_OUT := docs/benchmarks.md

# Every script's output goes into $(BENCH_OUT) under its own heading with the command, the date
# and the machine, and to the terminal as it comes. The file is assembled in $(BENCH_OUT).part
# and replaces the old one at the end, so an interrupted run keeps both; a failing script is
# recorded with its exit status, the others still run, and make then fails.
bench: install
	@machine="$$(nproc) cores, $$(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -n 1)"; \
	failed=""; \
	{ echo "# Benchmarks"; echo; \
	  echo "Written by \`make bench\`. What each benchmark measures and how to read it: [speed.md](speed.md)."; \
	} > $(BENCH_OUT).part; \
	for s in $(BENCH_SCRIPTS); do \
	  echo "== python scripts/$$s.py" >&2; \
	  { echo; echo "## $$s.py"; echo; \
	    echo "\`python scripts/$$s.py\` on $$machine, $$(date -u '+%Y-%m-%d %H:%M UTC')"; \
	    echo; echo '```text'; } >> $(BENCH_OUT).part; \
	  $(PY) scripts/$$s.py 2>&1 | tee -a $(BENCH_OUT).part; \
	  status=$${PIPESTATUS[0]}; \
	  if [ $$status -ne 0 ]; then echo "(exit status $$status)" >> $(BENCH_OUT).part; failed="$$failed $$s"; fi; \
	  echo '```' >> $(BENCH_OUT).part; \
	done; \
	mv $(BENCH_OUT).part $(BENCH_OUT); \
	echo "wrote $(BENCH_OUT)"; \
	if [ -n "$$failed" ]; then echo "failed:$$failed" >&2; exit 1; fi

lint: install
	$(VENV)/bin/ruff check .

clean:
	rm -rf $(VENV) build dist *.egg-info
