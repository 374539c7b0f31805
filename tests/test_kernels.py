"""The per-process choice of decision kernels (thinkfast.robot.kernels): the variable is read and
checked, numpy keeps numba out of the process, and both choices fly the same throws to the same
outcomes."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.conftest import ROBOT_TOML
from thinkfast.errors import ConfigError
from thinkfast.robot import kernels


def _world(tree_path):
    from thinkfast.control.config import RunConfig
    from thinkfast.robot.model import load_robot
    from thinkfast.sim.camera import CameraModelConfig
    from thinkfast.sim.controller import ServoConfig
    from thinkfast.sim.lockstep import World
    from thinkfast.tree.file import load_tree

    return World(
        load_tree(tree_path),
        load_robot(ROBOT_TOML),
        RunConfig(),
        ServoConfig(),
        CameraModelConfig(),
    )


def test_the_variable_defaults_to_compiled_and_refuses_an_unknown_choice_by_name():
    assert kernels._from_environment("") == "compiled"  # numba is installed here
    assert kernels._from_environment(" numpy ") == "numpy"
    with pytest.raises(
        ConfigError, match="THINKFAST_KERNELS: 'fast': expected one of compiled, numpy"
    ):
        kernels._from_environment("fast")
    with pytest.raises(ConfigError, match="THINKFAST_KERNELS"):
        kernels.use("fast")


def test_a_numpy_process_decides_without_importing_numba(small_tree_015):
    """A simulator process with THINKFAST_KERNELS=numpy builds the planners and flies a throw
    of decisions, and numba is never imported."""
    code = (
        "import sys\n"
        "from tests.test_kernels import _world\n"
        "from thinkfast.sim.cli_options import load_throws\n"
        "from thinkfast.sim.lockstep import simulate\n"
        f"out = simulate(_world({str(small_tree_015)!r}), load_throws(1, 4, None, 'still=1', 0)[0],"
        " 'tree', seed=4)\n"
        "print(out.decisions, 'numba' in sys.modules)\n"
    )
    env = dict(os.environ, THINKFAST_KERNELS="numpy")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    run = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=root, capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr
    decisions, numba = run.stdout.split()
    assert int(decisions) > 0 and numba == "False", run.stdout


def test_compiled_and_numpy_kernels_fly_the_same_throws_to_the_same_outcomes(small_tree_015):
    """Still and wind-up throws with the tree planner, flown in lockstep once with each choice:
    every outcome field equal (floats by their exact repr)."""
    from thinkfast.sim.bench import run_bench
    from thinkfast.sim.cli_options import load_throws

    throws = load_throws(3, 5, None, "still=0.5,windup=0.5", 0)
    rows = {}
    for choice in ("numpy", "compiled"):
        before = kernels.use(choice)
        try:
            rows[choice] = run_bench(lambda: _world(small_tree_015), throws, ["tree"], seed=5)
        finally:
            kernels.use(before)
    assert sum(r.decisions for r in rows["numpy"]) > 0
    assert repr(rows["numpy"]) == repr(rows["compiled"])
