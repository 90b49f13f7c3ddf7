# Two entry points, both safe on a fresh clone with only python3 and make:
#   make demo   set up .venv and run the main job (the multi-process demo)
#   make test   set up .venv and run the test suite but its longest tests (make test-long)
# and checks CI runs as well:
#   make test-long     the longest tests (pytest.mark.long), which make test leaves out
#   make test-kernels  the unit and property tests again on other floating-point paths (OpenBLAS kernels,
#                      BLAS threads, numpy without AVX-512), as on other CPUs
#   make test-lowest   set up .venv-lowest with every dependency at its lower bound, run a subset
#   make test-iterative  the certificate tests with every spectral radius computed matrix-free (ARPACK)
# the documentation site (Sphinx, offline, warnings are errors; executes the tutorials):
#   make docs     docs/_build/html/index.html
# and an example:
#   make sensors  a run on live sensors: splitspec run examples/sensors/chain.yaml beside its sensor publisher
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
LOWEST ?= .venv-lowest
# unit tests, the multi-process runtime, the property tests at a fifth of their examples and derandomized
# (the same examples every run: this gate checks the versions, it does not hunt); not the test pairing
# compose.yaml's router image with the installed eclipse-zenoh (deliberately older here)
LOWEST_TESTS ?= tests/unit tests/integration/test_runtime.py tests/property \
	--deselect tests/unit/test_compose.py::test_router_image_matches_the_python_package

# The numerical tests under floating-point paths other than this machine's: OpenBLAS picks its kernels
# from the CPU at run time and each kernel sums in its own order (Prescott: SSE3, Sandybridge: AVX,
# Haswell: AVX2 and FMA, as on AMD EPYC), over 1 or 2 threads; numpy's own loops use the widest SIMD
# the CPU has (the last variant turns AVX-512 off, as on an AVX2-only CPU).  A test that compares
# floats of different paths exactly fails here before it fails on a user's machine.  x86-64 only
# (the kernel names are OpenBLAS's x86 ones); SkylakeX/Zen-only kernels are not forced (they crash on
# CPUs without their instructions).
# The unit tests with no floating-point kernel in them (files, disk retention, recordings, CLI and scenario
# errors, the code's own layout, processes) run once, in make test: 147 s of each variant's 474 s (issue 44).
KERNEL_NOT_NUMERIC = retention cli_input scenario_errors recorder architecture records dependencies forks \
	recording_view recording_network one_place api_docs
KERNEL_TESTS ?= tests/unit tests/property $(foreach t,$(KERNEL_NOT_NUMERIC),--ignore=tests/unit/test_$(t).py)
KERNEL_PYTEST = RERUN_ANALYTICS=0 $(BIN)/python -m pytest -p no:cacheprovider $(PARALLEL) $(KERNEL_TESTS)

.PHONY: demo docs sensors test test-long test-iterative test-kernels test-lowest setup clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,control]'
	touch $@

demo: setup
	$(BIN)/splitspec design examples/paper_discrete.yaml
	RERUN_ANALYTICS=0 $(BIN)/splitspec run examples/paper_discrete.yaml --out out/demo

# the run in the background, the publisher (its own process, plain Zenoh) finds it through out/sensors and stops
# when it ends; the make target fails if the run does
sensors: setup
	RERUN_ANALYTICS=0 $(BIN)/splitspec run examples/sensors/chain.yaml --out out/sensors & run=$$!; \
	$(BIN)/python examples/sensors/publisher.py examples/sensors/chain.yaml --from-run out/sensors --dropout 0.05; \
	wait $$run

# -W --keep-going: every warning fails the build, all of them listed (a broken link between pages, a malformed
# docstring, a missing page, a failed tutorial); not -n: the docstrings name types in prose; -E: read every
# page again (the generated ones are rewritten each build)
docs: $(VENV)/.docs-installed
	rm -rf docs/_build
	RERUN_ANALYTICS=0 $(BIN)/python -m sphinx -W --keep-going -E -q -b html docs docs/_build/html
	@echo "docs: open docs/_build/html/index.html"

$(VENV)/.docs-installed: $(VENV)/.installed
	$(BIN)/python -m pip install --quiet -e '.[dev,docs]'
	touch $@

# two workers (pytest-xdist) share out every test (tests/conftest.py says why the deployments' tests are not kept
# on one of them); the property tests at half their examples (SPLITSPEC_PROPERTY_SCALE: make test-kernels runs them
# in full three times, under other floating-point paths)
WORKERS ?= 2
PARALLEL = -n $(WORKERS) --dist loadgroup --durations=25
TEST_PROPERTY_SCALE ?= 0.5

test: setup
	RERUN_ANALYTICS=0 SPLITSPEC_PROPERTY_SCALE=$(TEST_PROPERTY_SCALE) $(BIN)/python -m pytest $(PARALLEL) -m "not long"

# the tests marked long (pytest.mark.long: the longest, 17 to 70 s each on 2 cores), which make test leaves out to
# keep under 15 minutes on 2 cores; CI runs both
test-long: setup
	RERUN_ANALYTICS=0 SPLITSPEC_PROPERTY_SCALE=$(TEST_PROPERTY_SCALE) $(BIN)/python -m pytest $(PARALLEL) -m long

# The certificate tests again with every spectral radius of the spectral q computed by ARPACK on the matrix-free
# operator (splitspec_core/synthesis/spectral.py), which by default only designs above 300 unknowns take: both paths give
# the same q and verdicts (tests/conftest.py reads SPLITSPEC_TEST_EIGENVALUES).
CERTIFICATE_TESTS ?= tests/unit/test_certificates.py tests/unit/test_design_at_scale.py tests/unit/test_loss_certificate.py \
	tests/unit/test_paper_section5.py tests/unit/test_resilience_runtime.py tests/property/test_design_properties.py \
	tests/property/test_imperfect_models.py
test-iterative: setup
	SPLITSPEC_TEST_EIGENVALUES=iterative RERUN_ANALYTICS=0 $(BIN)/python -m pytest -p no:cacheprovider $(PARALLEL) \
	  $(CERTIFICATE_TESTS)

test-kernels: setup
	@if [ "$$(uname -m)" != x86_64 ]; then echo "test-kernels: x86-64 only (OpenBLAS core names), skipped"; exit 0; fi; \
	set -e; \
	echo "== OpenBLAS Prescott kernels, 1 thread"; \
	OPENBLAS_CORETYPE=Prescott OPENBLAS_NUM_THREADS=1 $(KERNEL_PYTEST); \
	echo "== OpenBLAS Sandybridge kernels, 2 threads"; \
	OPENBLAS_CORETYPE=Sandybridge OPENBLAS_NUM_THREADS=2 $(KERNEL_PYTEST); \
	echo "== OpenBLAS Haswell kernels, 2 threads, numpy without AVX-512"; \
	OPENBLAS_CORETYPE=Haswell OPENBLAS_NUM_THREADS=2 \
	  NPY_DISABLE_CPU_FEATURES="$$($(BIN)/python tests/platform_info.py --wide-simd)" $(KERNEL_PYTEST)

# --build-constraint (pip >= 25.3, hence the pip upgrade first): the build backend's isolated environment
# gets the oldest allowed setuptools too.
$(LOWEST)/.installed: pyproject.toml .ci/lowest_constraints.py
	rm -rf $(LOWEST)
	$(PY) -m venv $(LOWEST)
	$(LOWEST)/bin/python -m pip install --quiet --upgrade pip
	$(PY) .ci/lowest_constraints.py dev > $(LOWEST)/constraints.txt
	$(LOWEST)/bin/python -m pip install --quiet -c $(LOWEST)/constraints.txt \
	  --build-constraint $(LOWEST)/constraints.txt -e '.[dev]'
	touch $@

test-lowest: $(LOWEST)/.installed
	@$(LOWEST)/bin/python -m pip list --format=freeze 2>/dev/null \
	  | grep -i -E "^($$(sed -n '/^setuptools==/d; s/==.*//p' $(LOWEST)/constraints.txt | paste -sd'|'))==" | paste -sd' ' \
	  | sed 's/^/lowest versions: /'
	RERUN_ANALYTICS=0 HYPOTHESIS_PROFILE=ci SPLITSPEC_PROPERTY_SCALE=0.2 $(LOWEST)/bin/python -m pytest $(LOWEST_TESTS)

clean:
	rm -rf $(VENV) $(LOWEST) build *.egg-info
