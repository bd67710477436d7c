"""The pin of NumPy's and OpenBLAS's CPU paths: what it sets where, that NumPy's float32 power then equals the C
library's powf element for element (it did not with NumPy's AVX-512 loops), and that the committed state's sampled
views render to their recorded bytes here."""
import os
import subprocess
import sys

import pytest

from gtsweep.core.numeric_backends import PINNED, USER_SWITCHES, pinned_variables

X86_V3 = "processor\t: 0\nflags\t\t: fpu sse2 avx avx2 fma bmi1 bmi2 abm f16c movbe avx512f\n"


def test_pins_an_x86_64_machine_with_avx2():
    assert pinned_variables({}, "x86_64", X86_V3) == PINNED == {"NPY_ENABLE_CPU_FEATURES": "X86_V3",
                                                                 "OPENBLAS_CORETYPE": "Haswell"}


@pytest.mark.parametrize("environ, kept", [({"NPY_ENABLE_CPU_FEATURES": "X86_V4"}, "OPENBLAS_CORETYPE"),
                                           ({"NPY_DISABLE_CPU_FEATURES": "X86_V4"}, "OPENBLAS_CORETYPE"),
                                           ({"OPENBLAS_CORETYPE": "SkylakeX"}, "NPY_ENABLE_CPU_FEATURES")])
def test_a_users_own_switch_stands(environ, kept):
    """The user's switch replaces its pinned variable (NumPy refuses both of its switches at once); the other
    variable is still pinned."""
    assert pinned_variables(environ, "x86_64", X86_V3) == {kept: PINNED[kept]}


@pytest.mark.parametrize("machine, cpuinfo", [("aarch64", X86_V3), ("x86_64", None),
                                              ("x86_64", X86_V3.replace(" avx2", ""))])
def test_no_pin_where_numpy_would_refuse_it_or_it_means_nothing(machine, cpuinfo):
    """Without AVX2 NumPy refuses ``NPY_ENABLE_CPU_FEATURES=X86_V3`` at import; off x86-64 there is no such path."""
    assert pinned_variables({}, machine, cpuinfo) == {}


PROBE = """
import gtsweep, numpy as np
from gtsweep.core.numeric_backends import numpy_dispatch_pinned
x = np.random.default_rng(3).random(200_000, dtype=np.float32)
gamma = np.float32(1.37)
vector = x ** gamma
scalar = np.array([np.float32(v) ** gamma for v in x[:20_000]], np.float32)  # the C library's powf, one by one
print(numpy_dispatch_pinned(), int((vector[:20_000] != scalar).sum()))
"""


def test_float32_power_is_the_c_librarys_in_a_fresh_process():
    """``import gtsweep`` first: the array power equals powf bit for bit (SVML's differed in ~20 % of values)."""
    switches = {name for names in USER_SWITCHES.values() for name in names}
    env = {k: v for k, v in os.environ.items() if k not in switches}
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.split() == ["True", "0"], out.stdout + out.stderr


@pytest.mark.slow
def test_the_committed_states_sampled_views_render_to_their_recorded_bytes(tmp_path):
    """One recorded image or pair of each split (synthetic, incremental, absolute) renders here to its fingerprint,
    as ``python -m gtsweep.reproduction document`` checks before it writes."""
    from gtsweep.reproduction import checks
    from gtsweep.reproduction import state as states

    assert checks.rerender(states.load(states.STATE_DIR), str(tmp_path)) == 3


def test_the_audit_renders_every_recorded_item_and_names_those_that_differ(tmp_path):
    """Two recorded pairs of one texture, the second's fingerprint altered: both are rendered and compared, and
    only the altered one is named (``python -m gtsweep.reproduction audit``)."""
    from gtsweep.reproduction import checks
    from gtsweep.reproduction import state as states

    recorded = checks.recorded_items(states.load(states.STATE_DIR))["incremental"]
    items = {item: recorded[item] for item in ("carpet/incremental/000", "carpet/incremental/001")}
    items["carpet/incremental/001"] = "0" * 16
    held = states.State({"textures": ["carpet"]}, [{"split": "incremental", "items": items}], {})
    assert checks.audit(held, str(tmp_path), ["carpet"]) == (2, ["carpet/incremental/001"])


def test_the_audit_refuses_a_texture_the_state_does_not_hold(tmp_path):
    from gtsweep.core.errors import BadInput
    from gtsweep.reproduction import checks
    from gtsweep.reproduction import state as states

    with pytest.raises(BadInput, match="no recorded texture gravel"):
        checks.audit(states.State({"textures": ["carpet"]}, [], {}), str(tmp_path), ["gravel"])
