import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

os.environ.setdefault("RERUN_ANALYTICS", "0")


@pytest.fixture
def examples_dir() -> Path:
    return EXAMPLES
