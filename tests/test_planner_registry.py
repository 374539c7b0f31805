"""The planner registry (thinkfast.control.planners.registry) is the one list of planners.

Claims: a planner added as one class plus one registry entry (here a toy defined in this file
and registered at run time, no other file edited) is taken by ``thinkfast-run --planner``, by
``thinkfast-sim bench --planners`` (which flies it in lockstep and reports it) and by a sweep
file's ``planners``, and refused by all three once it is unregistered; the built-in entries
load planner classes and the hedge variants are the tree planner with each ``[hedge] mode``.
"""

from __future__ import annotations

import json
import math

import pytest

from tests.conftest import small_tree_config
from thinkfast.control.config import RunConfig
from thinkfast.control.executor import Executor
from thinkfast.control.hedge import HEDGE_MODES
from thinkfast.control.planners import registry
from thinkfast.control.planners.base import STAY, Act, Belief, EpisodeLog, Planner
from thinkfast.control.planners.tree import TreePlanner
from thinkfast.errors import ConfigError
from thinkfast.sim.planners import lockstep_planners, online_planners

TOY = "first-guess"


class FirstGuess(Planner):
    """A toy: to the goal nearest the first crossing predicted, never re-targeted."""

    def decide(self, b: Belief, ep: EpisodeLog) -> Act:
        c = b.crossing
        if b.executing or not c.ok:
            return STAY
        goal = self.tree.nearest_goal(c.mean[:2])
        return Act(leave=True, value=1.0, follow=self.steer(goal, b.t_now))


@pytest.fixture
def toy():
    """The toy registered for one test (and removed again)."""
    registry.register(registry.Entry(TOY, FirstGuess, "toy: the first guess"))
    yield TOY
    registry.unregister(TOY)


def test_a_registered_planner_is_in_every_list_and_gone_once_unregistered(toy):
    assert toy in registry.names(online=True) and toy in online_planners()
    assert toy in lockstep_planners() and "oracle" in lockstep_planners()
    assert "toy: the first guess" in registry.describe()
    registry.unregister(toy)
    assert toy not in lockstep_planners() and toy not in online_planners()
    with pytest.raises(ValueError, match=TOY):
        registry.get(toy)
    registry.register(registry.Entry(TOY, FirstGuess))  # for the fixture to remove


def test_names_are_unique_and_builtins_stay():
    with pytest.raises(ValueError, match="registered already"):
        registry.register(registry.Entry("tree", FirstGuess))
    with pytest.raises(ValueError, match="built in"):
        registry.unregister("naive")
    assert registry.names(online=True) == (
        "tree",
        "tree-rest",
        "naive",
        "naive-paper",
        "mpc",
        "mpc-soft",
        "jpl",
        "jpl-filter",
    )


def test_builtin_entries_load_planners_and_the_hedge_variants_set_each_mode():
    cfg = RunConfig()
    for e in registry.BUILTIN:
        assert issubclass(e.load(), Planner), e.name
    for mode in HEDGE_MODES:
        e = registry.get(f"tree-hedge-{mode}")
        assert e.load() is TreePlanner and not e.online
        assert e.configure(cfg).hedge.mode == mode
        assert e.configure(cfg).choice == cfg.choice  # nothing else changes
    with pytest.raises(ValueError, match="hedge.nope"):
        registry.Entry("x", FirstGuess, settings=(("hedge.nope", 1),)).configure(cfg)


def _daemon_error(capsys, *args: str) -> str:
    """``thinkfast-run`` run in this process with ``args``: its one-line error."""
    from thinkfast.daemon.cli import main

    with pytest.raises(SystemExit) as exc:
        main(list(args))
    assert exc.value.code != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_the_daemon_cli_takes_the_registered_planner(toy, capsys, tmp_path):
    tree = str(tmp_path / "tree.h5")  # never read: the options are checked first
    # the planner passes: the next check (the log level) is the one that fails
    err = _daemon_error(capsys, "--tree", tree, "--planner", toy, "--log-level", "loud")
    assert "--log-level" in err and "--planner" not in err
    err = _daemon_error(capsys, "--tree", tree, "--planner", "tree-hedge-mean")
    assert "--planner" in err and "tree-hedge-mean" in err and toy in err  # lockstep only
    registry.unregister(toy)
    err = _daemon_error(capsys, "--tree", tree, "--planner", toy, "--log-level", "loud")
    assert "--planner" in err and TOY in err
    registry.register(registry.Entry(TOY, FirstGuess))


def test_the_bench_cli_flies_the_registered_planner_in_lockstep(toy, small_tree_015, capsys):
    from thinkfast.sim.cli import main

    args = ["bench", "--tree", str(small_tree_015), "--throws", "3", "--feints", "1", "-j", "1"]
    with pytest.raises(SystemExit) as exc:
        main([*args, "--planners", f"{toy},naive", "--reference", toy, "--json"])
    assert exc.value.code == 0
    summary = json.loads(capsys.readouterr().out)
    assert list(summary["planners"]) == [toy, "naive"]
    assert summary["paired"]["reference"] == toy
    e = summary["planners"][toy]
    assert summary["throws"] == 3 and summary["feints"] == 1
    assert e["throws"] == 3 and sum(e["why"].values()) == 3
    assert e["by_kind"]["feint"]["feints"] == 1
    registry.unregister(toy)
    with pytest.raises(SystemExit) as exc:
        main([*args, "--planners", f"{toy},naive"])
    assert exc.value.code != 0 and "--planners" in capsys.readouterr().err
    registry.register(registry.Entry(TOY, FirstGuess))


def test_a_lockstep_run_with_the_registered_planner_flies(toy, small_tree_015, robot):
    from thinkfast.sim.camera import CameraModelConfig
    from thinkfast.sim.controller import ServoConfig
    from thinkfast.sim.lockstep import World, simulate
    from thinkfast.sim.throws import ThrowConfig, sample_throws
    from thinkfast.tree.file import load_tree

    world = World(load_tree(small_tree_015), robot, RunConfig(), ServoConfig(), CameraModelConfig())
    for i, throw in enumerate(sample_throws(ThrowConfig(), 3, 11)):
        o = simulate(world, throw, toy, seed=100 + i)
        assert o.planner == toy and o.why in ("blocked", "late", "missed")
        assert o.moved and o.decisions >= 1 and not math.isnan(o.commit_start)
    ex = Executor(world.tree, robot, world.cfg, toy)  # the executor built the toy
    assert isinstance(ex.planner, FirstGuess) and ex.name == toy


def test_a_sweep_file_takes_the_registered_planner(toy, tmp_path):
    from thinkfast.sweep.spec import load_sweep

    small_tree_config(tmp_path, spacing=0.45, depth=1).rename(tmp_path / "base.toml")
    path = tmp_path / "sweep.toml"
    text = '[sweep]\ncompile_config = "base.toml"\nplanners = ["{}", "oracle"]\nthrows = 2\n'
    path.write_text(text.format(toy))
    sweep = load_sweep(path)
    assert sweep.settings.planners == (toy, "oracle") and sweep.reference == toy
    path.write_text(text.format("no-such"))
    with pytest.raises(ConfigError) as exc:
        load_sweep(path)
    assert exc.value.key == "sweep.planners" and "no-such" in exc.value.problem
    assert toy in exc.value.problem  # the message lists the registry's planners
