"""What a test run's floating-point results depend on: versions, CPU, and the BLAS kernel actually used.

Two machines with the same versions can still sum in other orders: OpenBLAS picks its kernels at run
time from the CPU (``OPENBLAS_CORETYPE`` overrides it) and splits work over ``OPENBLAS_NUM_THREADS``
threads, and numpy dispatches its own loops to the widest SIMD the CPU has (``NPY_DISABLE_CPU_FEATURES``
narrows it).  ``pytest`` prints these lines in its header (``tests/conftest.py``), and ``.ci/run``
prints them before anything runs, so a failure report says where it happened.

``python tests/platform_info.py`` prints them; ``--wide-simd`` prints only numpy's dispatch targets beyond
AVX2 that this CPU uses (what ``make test-kernels`` turns off to run numpy's loops as on an AVX2-only CPU).
"""

from __future__ import annotations

import ctypes
import glob
import os
import platform
from importlib import metadata

PACKAGES = ("numpy", "scipy", "eclipse-zenoh", "rerun-sdk", "pyarrow", "msgpack", "PyYAML", "matplotlib",
            "pytest", "hypothesis")
ENV = ("OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "NPY_DISABLE_CPU_FEATURES")


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def openblas_cores() -> dict:
    """``{library: (core name, threads)}`` of every OpenBLAS numpy and scipy loaded (they bundle their own)."""
    import numpy
    import scipy
    import scipy.linalg  # noqa: F401 - loads scipy's OpenBLAS

    out = {}
    for pkg in (numpy, scipy):
        for lib in sorted(glob.glob(os.path.join(os.path.dirname(pkg.__file__) + ".libs", "*openblas*"))):
            try:
                dll = ctypes.CDLL(lib)
            except OSError:
                continue
            core = threads = None
            # scipy-openblas builds prefix their symbols (numpy's is the 64-bit-integer one, suffix 64_);
            # older scipy wheels bundle a plain OpenBLAS
            for prefix, suffix in (("scipy_", "64_"), ("scipy_", ""), ("", "")):
                try:
                    f = getattr(dll, f"{prefix}openblas_get_corename{suffix}")
                except AttributeError:
                    continue
                f.restype = ctypes.c_char_p
                core = f().decode()
                try:
                    threads = int(getattr(dll, f"{prefix}openblas_get_num_threads{suffix}")())
                except AttributeError:
                    pass
                break
            out[f"{pkg.__name__}: {os.path.basename(lib)}"] = (core or "unknown", threads)
    return out


def wide_simd() -> str:
    """numpy's dispatch targets beyond AVX2 (x86-64-v3) that this CPU uses, space-separated ("" if none)."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:
        return ""
    return " ".join(k for k in __cpu_dispatch__ if __cpu_features__.get(k) and (k.startswith("AVX512")
                                                                                or k == "X86_V4"))


def numpy_simd() -> str:
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:
        return "unknown"
    return " ".join(k for k in __cpu_dispatch__ if __cpu_features__.get(k)) or "baseline only"


def lines() -> list:
    out = [f"python {platform.python_version()} on {platform.system()} {platform.machine()}, "
           f"{os.cpu_count()} CPUs: {cpu_model()}"]
    versions = []
    for name in PACKAGES:
        try:
            versions.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            versions.append(f"{name} (not installed)")
    out.append("versions: " + ", ".join(versions))
    for lib, (core, threads) in openblas_cores().items():
        out.append(f"OpenBLAS kernel {core}, {threads} thread(s) ({lib})")
    out.append(f"numpy SIMD dispatch: {numpy_simd()}")
    env = [f"{k}={os.environ[k]}" for k in ENV if k in os.environ]
    out.append("environment: " + (" ".join(env) if env else "no BLAS or SIMD overrides"))
    return out


if __name__ == "__main__":
    import sys

    print(wide_simd() if sys.argv[1:] == ["--wide-simd"] else "\n".join(lines()))
