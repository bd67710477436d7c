"""Where the torch-run learned methods (ALIKED, DISK, LightGlue) compute: ``runner.device`` = cpu, cuda or auto.

``auto`` is ``cuda`` when ``torch.cuda.is_available()`` in the driver, else ``cpu``; asking for ``cuda`` where there
is none is one line and exit 2 before any work. The driver resolves the setting once per run; every task is
given the resolved device explicitly and computes inside :func:`using`, so a worker on a GPU node still computes
on the CPU in a cpu run. OpenCV's methods and XFeat (OpenCV's dnn) always run on the CPU.

GPU numbers differ from CPU numbers in the last bits (other kernels, other summation orders), so the device enters
the cell hash and the keypoint-cache key of the methods it moves -- only where it is not cpu: a CPU run's hashes and
keys are the ones it had before the setting existed. :mod:`gtsweep.stages.gpu_tolerance` states how far a GPU's
numbers may differ.
"""
from __future__ import annotations

import contextlib
import contextvars
import functools
from typing import Iterator

from gtsweep.core.errors import BadInput

CPU, CUDA, AUTO = "cpu", "cuda", "auto"
#: The values of ``runner.device``.
SETTINGS = (AUTO, CPU, CUDA)
#: The methods that torch runs, per group: the ones a device moves.
TORCH_METHODS = {
    "detector": frozenset({"aliked_n16", "aliked_n16rot", "disk"}),
    "descriptor": frozenset({"aliked_n16", "aliked_n16rot", "disk"}),
    "matcher": frozenset({"lightglue"}),
}

#: The device of the computation running in this context (a context variable: no module-level run state).
_current: contextvars.ContextVar[str] = contextvars.ContextVar("gtsweep_device", default=CPU)


def cuda_available() -> bool:
    """Whether torch is installed and sees a CUDA device (torch is imported only here and by the methods)."""
    try:
        import torch
    except ImportError:
        return False
    return bool(torch.cuda.is_available())


def resolve(setting: str | None, needs_torch: bool = True) -> str:
    """The device a run computes on for ``runner.device`` = ``setting`` (None: auto). ``needs_torch``: whether the
    run has a torch method at all (if not, it is cpu without importing torch)."""
    setting = AUTO if setting is None else str(setting)
    if setting not in SETTINGS:
        raise BadInput(f"runner.device must be one of {', '.join(SETTINGS)}, got {setting!r}")
    if setting == CPU or not needs_torch:
        return CPU
    available = cuda_available()
    if setting == CUDA and not available:
        raise BadInput("runner.device=cuda, but torch sees no CUDA device (torch.cuda.is_available() is False); "
                       "use runner.device=cpu or auto")
    return CUDA if available else CPU


def moves(group: str, name: str | None) -> bool:
    """Whether the device decides where method ``name`` of ``group`` computes."""
    return name in TORCH_METHODS.get(group, ())


def device_of(group: str, name: str | None, device: str) -> str:
    """Where method ``name`` computes in a run on ``device``."""
    return device if moves(group, name) else CPU


def key_entry(group: str, name: str | None, device: str) -> dict:
    """What a hash or key of method ``name`` adds for ``device``: ``{"device": ...}`` where the method moves to a
    device other than the CPU, else nothing (so CPU hashes and keys stay as they were)."""
    where = device_of(group, name, device)
    return {} if where == CPU else {"device": where}


@functools.lru_cache(maxsize=1)
def full_precision_cuda() -> None:
    """CUDA as close to the CPU's numbers as torch allows: float32 matrix products and convolutions without
    TF32 (torch's default for cuDNN convolutions is TF32, ~1e-3 relative error), deterministic cuDNN kernels."""
    import torch

    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    torch.backends.cudnn.benchmark = False
    torch.backends.cudnn.deterministic = True


def current() -> str:
    """The device of the computation running in this process (:func:`using`); cpu outside any."""
    return _current.get()


@contextlib.contextmanager
def using(device: str | None) -> Iterator[str]:
    """Run the torch methods of the enclosed computation on ``device`` (None: cpu); restored afterwards."""
    device = CPU if device is None else device
    if device not in (CPU, CUDA):
        raise BadInput(f"a task's device must be {CPU} or {CUDA}, got {device!r}")
    if device == CUDA:
        full_precision_cuda()
    token = _current.set(device)
    try:
        yield device
    finally:
        _current.reset(token)
