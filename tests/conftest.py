import os
from pathlib import Path

import pytest
from hypothesis import settings

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

os.environ.setdefault("RERUN_ANALYTICS", "0")
# no design cache in the tests (synthesis/design_cache.py): each test designs what it checks, whatever ran before it
# (tests/unit/test_design_cache.py turns it on in a folder of its own)
os.environ["SPLITSPEC_CACHE"] = "off"

# HYPOTHESIS_PROFILE=ci (.ci/run and make test-lowest): every property test draws the same examples on every run
# (derandomized: CI lands or not on the code, never on the draw); unset, each run draws new ones (a hunt: how
# tests/property/*'s kept @examples were found).  Loaded here, before any test module is imported: a test's
# @settings falls back to the profile in force when the test is decorated.
settings.register_profile("ci", derandomize=True)
if os.environ.get("HYPOTHESIS_PROFILE"):
    settings.load_profile(os.environ["HYPOTHESIS_PROFILE"])


@pytest.fixture
def examples_dir() -> Path:
    return EXAMPLES


def pytest_report_header(config):
    """Versions, CPU, OpenBLAS kernel and numpy SIMD: what floating-point results depend on."""
    from tests.platform_info import lines

    return lines()


# SPLITSPEC_TEST_EIGENVALUES=iterative (make test-iterative): every spectral radius of a design's spectral q
# (splitspec_core.synthesis.bounds.error_radius) by ARPACK on the matrix-free operator, whatever its size, so the
# certificate tests check that path too (by default small designs take the dense path).
if os.environ.get("SPLITSPEC_TEST_EIGENVALUES") == "iterative":
    @pytest.fixture(autouse=True)
    def _iterative_eigenvalues(monkeypatch):
        from splitspec_core.synthesis import spectral

        monkeypatch.setattr(spectral, "DENSE_MAX", 0)


# make test runs two workers (pytest-xdist): they share out every test, so two deployments' tests (integration,
# chaos) may run at once, each paced run beside the other's processes; their timeouts allow for it.  (A hook here
# once marked them for one worker, one after another; pytest-xdist read the marks before it ran, so it never had
# an effect -- measured: the deployments' tests of one suite took 1320 s of its 1184 s -- and one worker for them
# would make them alone longer than the whole suite is.)
