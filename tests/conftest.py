import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

os.environ.setdefault("RERUN_ANALYTICS", "0")


@pytest.fixture
def examples_dir() -> Path:
    return EXAMPLES


def pytest_report_header(config):
    """Versions, CPU, OpenBLAS kernel and numpy SIMD: what floating-point results depend on."""
    from tests.platform_info import lines

    return lines()
