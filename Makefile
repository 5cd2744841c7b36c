# Two commands do all the set-up on a fresh clone:
#   make demo   - the end-to-end demo on the simulated sensor
#   make test   - the test suite
# Each creates .venv and builds the Cython extensions itself.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(VENV)/bin/pip
STAMP  := $(VENV)/.installed
EXTRAS := $(VENV)/.installed-extras
PYX    := $(shell find springtrack firmware_sim -name '*.pyx' -o -name '*.pxd' -o -name '*.h' | sort)
# pip installs the packages without compiling (SPRINGTRACK_ONLY matches no module);
# `build` compiles the extensions in place, two at a time, and later only what changed
NO_EXT := SPRINGTRACK_ONLY=none

.PHONY: demo test build bench clean qemu

# what the library, the firmware, the host and the demo need (the demo draws: plots)
$(STAMP): pyproject.toml setup.py
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q "setuptools>=64" wheel "cython>=3.0" "numpy>=1.24"
	$(NO_EXT) $(PIP) install -q --no-build-isolation -e '.[plots]'
	touch $(STAMP)

# what the tests add: the test tools, dask (the experiments), the microcontroller build,
# atheris (the fuzz targets)
$(EXTRAS): $(STAMP)
	$(NO_EXT) $(PIP) install -q --no-build-isolation -e '.[test,plots,sweep,mcu,dv,view,fuzz]'
	touch $(EXTRAS)

build: $(STAMP) $(PYX)
	$(PY) setup.py -q build_ext --inplace -j 2

demo: build
	$(VENV)/bin/hostctl demo

test: $(EXTRAS) build qemu
	SPRINGTRACK_ALL_TESTS=1 $(PY) -m pytest -q tests; rc=$$?; if [ $$rc -eq 5 ]; then echo "no tests ran"; exit 1; fi; exit $$rc

# the firmware image's tests boot it in QEMU (docs/mcu.md): installed when missing, as root
# (CI); otherwise those tests say how to install it
qemu:
	@command -v qemu-system-arm >/dev/null || { if [ "$$(id -u)" = 0 ]; then \
	  apt-get update -q && apt-get install -y -q --no-install-recommends qemu-system-arm; \
	else echo "qemu-system-arm is missing: sudo apt-get install qemu-system-arm"; fi; }

bench: build
	$(PY) benchmarks/kernel.py

clean:
	rm -rf $(VENV) build springtrack/*.so springtrack/*/*.so firmware_sim/*.so tests/*.so tests/*.c tests/support/*.so tests/support/*.c
