import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

os.environ.setdefault("RERUN_ANALYTICS", "0")
# no design cache in the tests (synthesis/design_cache.py): each test designs what it checks, whatever ran before it
# (tests/unit/test_design_cache.py turns it on in a folder of its own)
os.environ["SPLITSPEC_CACHE"] = "off"


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


# make test runs two workers (pytest-xdist, --dist loadgroup): the tests that start a deployment's processes
# (integration, chaos) stay on one worker, one after another as before (their paced rounds and timeouts assume
# the machine's other core is not another deployment); the unit and property tests share out the rest
RUNTIME_FOLDERS = ("integration", "chaos")


def pytest_collection_modifyitems(config, items):
    if not config.pluginmanager.hasplugin("xdist"):
        return
    for item in items:
        if Path(str(item.fspath)).parent.name in RUNTIME_FOLDERS:
            item.add_marker(pytest.mark.xdist_group("runtime"))
