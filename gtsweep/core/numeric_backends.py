"""The same bytes on AVX2 and AVX-512 machines: NumPy's SIMD dispatch and OpenBLAS's kernel pinned to what a machine
with AVX2 runs, before NumPy loads (4 of 1500 recorded views still differ, cause not found: docs/reproduction_run.md).

Why: NumPy's AVX-512 loops compute ``float32 ** float`` with Intel's SVML, which rounds about one value in five
differently from the C library's ``powf`` that the AVX2 loops call; OpenBLAS's AVX-512 (SkylakeX) kernel multiplies
3x3 matrices in another order than its Haswell kernel. The data set's "another day" tone curve and its ground-truth
homographies go through both, so a view rendered on an AVX-512 machine differed in some pixels, and a pair's
ground truth in its last bits, from the same view rendered on an AVX2 machine. OpenCV's AVX-512 paths were measured
to give the same keypoints and descriptors as its AVX2 paths, so OpenCV is left as it is.

The pin sets, on Linux x86-64 machines whose CPU has the X86_V3 (AVX2) features, ``NPY_ENABLE_CPU_FEATURES=X86_V3``
(NumPy raises at import when asked for a feature the machine lacks, hence the check) and
``OPENBLAS_CORETYPE=Haswell``, each where the user has not set it (or, for NumPy, its counterpart
``NPY_DISABLE_CPU_FEATURES``). Child processes, Ray's workers among them, inherit it. It cannot act in a process
that imported NumPy before gtsweep; :func:`pin_this_process` then warns.

Not covered: other architectures and operating systems (aarch64, macOS), whose libm ``powf`` and BLAS kernels are
their own; there a view may render to other bytes, and ``python -m gtsweep.reproduction document`` says so in one
line when a sampled view's fingerprint differs from the state's.
"""
from __future__ import annotations

import os
import sys
import warnings

X86_V3_FLAGS = frozenset({"avx", "avx2", "fma", "bmi1", "bmi2", "abm", "f16c", "movbe"})  # /proc/cpuinfo names
PINNED = {"NPY_ENABLE_CPU_FEATURES": "X86_V3", "OPENBLAS_CORETYPE": "Haswell"}
#: Per pinned variable, the user's switches that replace it (NumPy refuses both of its switches at once).
USER_SWITCHES = {"NPY_ENABLE_CPU_FEATURES": ("NPY_ENABLE_CPU_FEATURES", "NPY_DISABLE_CPU_FEATURES"),
                 "OPENBLAS_CORETYPE": ("OPENBLAS_CORETYPE",)}


def _is_flags(line: str) -> bool:
    return line.partition(":")[0].strip() == "flags"


def cpu_flags(cpuinfo: str) -> frozenset[str]:
    """The feature flags of the first processor listed in ``/proc/cpuinfo``'s text."""
    found = next((line for line in cpuinfo.splitlines() if _is_flags(line)), "")
    return frozenset(found.partition(":")[2].split())


def pinned_variables(environ: dict, machine: str, cpuinfo: str | None) -> dict[str, str]:
    """The variables to set: :data:`PINNED` on an x86-64 machine with the X86_V3 features, each unless the user
    set one of its :data:`USER_SWITCHES` (their choice stands)."""
    if machine.lower() not in ("x86_64", "amd64") or cpuinfo is None or not X86_V3_FLAGS <= cpu_flags(cpuinfo):
        return {}
    return {name: value for name, value in PINNED.items()
            if not any(environ.get(switch) for switch in USER_SWITCHES[name])}


def _read_cpuinfo() -> str | None:
    """``/proc/cpuinfo`` up to its first ``flags`` line: the kernel writes the file as it is read, so the other
    processors' blocks (hundreds on a large machine) are never produced at every ``import gtsweep``."""
    lines = []
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as handle:
            for line in handle:
                lines.append(line)
                if _is_flags(line):
                    break
    except OSError:
        return None
    return "".join(lines)


def pin_this_process() -> dict[str, str]:
    """Set :func:`pinned_variables` in ``os.environ`` (so in every child); returns what it set. Warns when NumPy
    was loaded already with an AVX-512 target on: the pin then holds for the children only."""
    if sys.platform != "linux":
        return {}
    variables = pinned_variables(os.environ, os.uname().machine, _read_cpuinfo())
    os.environ.update(variables)
    if variables and "numpy" in sys.modules and not numpy_dispatch_pinned():
        warnings.warn("gtsweep: NumPy was imported before gtsweep, so its AVX-512 paths may stay on in this process "
                      "and rendered views may differ in their last bits from other machines' (import gtsweep first)",
                      RuntimeWarning, stacklevel=3)
    return variables


def numpy_dispatch_pinned() -> bool:
    """Whether this process's NumPy dispatches to no AVX-512 target (True off x86-64)."""
    from numpy._core._multiarray_umath import __cpu_dispatch__ as targets, __cpu_features__ as features
    return not any(features.get(name) for name in targets if name == "X86_V4" or "512" in name)
