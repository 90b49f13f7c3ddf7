"""The suite's float comparison (tests/numerics.py) and the kernel switch that `make test-kernels` relies on."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import ROOT
from tests.numerics import assert_close, max_rel_diff


def test_assert_close_is_relative_to_the_larger_norm():
    a = np.array([1e6, 1.0, -3.0])
    assert assert_close(a, a + 1e-7, rtol=1e-12) <= 1e-12  # 1e-7 of 1e6 is 1e-13
    with pytest.raises(AssertionError, match=r"xhat: differs by 1e-06 of the larger norm \(tolerance 1e-12\)"):
        assert_close(a, a + [0, 0, 1.0], rtol=1e-12, what="xhat")
    assert max_rel_diff(np.zeros(3), np.zeros(3)) == 0.0
    with pytest.raises(AssertionError, match="shapes differ"):
        assert_close(np.zeros(3), np.zeros(4), rtol=1.0)


def test_assert_close_and_nan():
    a = np.array([1.0, np.nan, 2.0])
    assert_close(a, a.copy(), rtol=0.0, equal_nan=True)
    with pytest.raises(AssertionError, match="non-finite entries at different places"):
        assert_close(a, np.array([1.0, 3.0, np.nan]), rtol=1.0, equal_nan=True)
    with pytest.raises(AssertionError, match="non-finite entries"):
        assert_close(a, a, rtol=1.0)  # NaN only with equal_nan


def kernel_under(env: dict) -> list:
    """The OpenBLAS kernels a fresh interpreter reports under ``env`` (one per bundled OpenBLAS)."""
    r = subprocess.run([sys.executable, str(ROOT / "tests" / "platform_info.py")], capture_output=True, text=True,
                       env={**os.environ, **env}, cwd=ROOT, timeout=60)
    assert r.returncode == 0, r.stderr
    return [ln.split()[2].rstrip(",") for ln in r.stdout.splitlines() if ln.startswith("OpenBLAS kernel")]


@pytest.mark.skipif(platform.machine() != "x86_64", reason="OpenBLAS x86-64 core names")
def test_the_kernel_override_takes_effect():
    """`make test-kernels` is only worth its minutes if OPENBLAS_CORETYPE really changes numpy's and scipy's kernels."""
    default = kernel_under({})
    assert default and "unknown" not in default, default  # both OpenBLAS libraries found and asked
    assert kernel_under({"OPENBLAS_CORETYPE": "Sandybridge"}) == ["Sandybridge"] * len(default)
    prescott = kernel_under({"OPENBLAS_CORETYPE": "Prescott"})
    assert len(set(prescott)) == 1 and prescott[0] not in ("Sandybridge", "Haswell", "SkylakeX"), prescott
