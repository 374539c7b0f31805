"""The test suite's own rules, checked on its source (so a new test cannot quietly break them).

1. A test that drives something on the wall clock (a real daemon, a simulated controller on its
   cycle, a throw published on its schedule) is marked ``realtime``: `make test` runs those one
   at a time after the rest, which run in parallel.
2. No test asserts an upper bound on a wall-clock duration or latency: such figures depend on
   the machine and its load and are measured by bench/ scripts (bench/wallclock.py,
   bench/egm_latency.py), not asserted.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
# Names that start something running on its own real-time schedule.
WALL_CLOCK_DRIVERS = {
    "DaemonRun",
    "ControllerRunner",
    "publish_throw",
    "publish_detections",
    "send_detections",
}
CLOCKS = {"perf_counter", "monotonic", "time", "perf_counter_ns", "monotonic_ns"}
# Variables that, in this suite, hold wall-clock durations.
WALL_NAMES = {"elapsed", "rtt", "rtts", "late", "lateness", "latency", "gaps", "close_s"}


def _modules() -> list[Path]:
    return sorted(TESTS.glob("test_*.py"))


def _is_clock_call(node: ast.AST) -> bool:
    return (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr in CLOCKS
        and isinstance(node.func.value, ast.Name)
        and node.func.value.id == "time"
    )


def _wall(node: ast.AST) -> bool:
    """Whether an expression reads the wall clock, or is (a statistic of) a variable named as a
    wall duration: ``elapsed``, ``np.median(rtts)``; a wait's own deadline does not count."""
    if isinstance(node, ast.Name):
        return node.id in WALL_NAMES
    if isinstance(node, ast.Call) and not _is_clock_call(node):
        if any(isinstance(a, ast.Name) and a.id in WALL_NAMES for a in node.args):
            return True
    return any(_is_clock_call(sub) for sub in ast.walk(node))


def _deadline(node: ast.AST) -> bool:
    return isinstance(node, ast.Name) and ("deadline" in node.id or node.id == "t_end")


def upper_bounds_on_wall_time(tree: ast.AST) -> list[int]:
    """Line numbers of asserts that bound a wall-clock expression from above."""
    lines = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Assert):
            continue
        for cmp in ast.walk(node.test):
            if not isinstance(cmp, ast.Compare):
                continue
            operands = [cmp.left, *cmp.comparators]
            for i, op in enumerate(cmp.ops):
                left, right = operands[i], operands[i + 1]
                if _deadline(left) or _deadline(right):
                    continue  # a wait that gives up: `assert time.monotonic() < deadline`
                if (isinstance(op, ast.Lt | ast.LtE) and _wall(left)) or (
                    isinstance(op, ast.Gt | ast.GtE) and _wall(right)
                ):
                    lines.append(node.lineno)
    return sorted(set(lines))


def _on_a_given_clock(call: ast.Call) -> bool:
    """A driver handed its clock (``clock=...``) runs on simulated time."""
    return any(k.arg == "clock" for k in call.keywords)


def _marked_realtime(fn: ast.FunctionDef) -> bool:
    for dec in fn.decorator_list:
        if "realtime" in ast.unparse(dec):
            return True
    return False


def unmarked_wall_clock_tests(tree: ast.Module) -> list[str]:
    """Test functions that use a wall-clock driver (directly, or through a fixture or helper
    defined in the same module) without the ``realtime`` mark."""
    funcs = {n.name: n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
    module_marked = any(
        isinstance(n, ast.Assign)
        and any(isinstance(t, ast.Name) and t.id == "pytestmark" for t in n.targets)
        and "realtime" in ast.unparse(n.value)
        for n in tree.body
    )

    def drives(name: str, seen: frozenset = frozenset()) -> bool:
        fn = funcs.get(name)
        if fn is None or name in seen:
            return False
        seen = seen | {name}
        for sub in ast.walk(fn):
            if isinstance(sub, ast.Call) and isinstance(sub.func, ast.Name):
                if sub.func.id in WALL_CLOCK_DRIVERS and not _on_a_given_clock(sub):
                    return True
            if isinstance(sub, ast.Call) and isinstance(sub.func, ast.Name):
                if not sub.func.id.startswith("test_") and drives(sub.func.id, seen):
                    return True
        return any(drives(a.arg, seen) for a in fn.args.args)

    return [
        name
        for name, fn in funcs.items()
        if name.startswith("test_")
        and not module_marked
        and not _marked_realtime(fn)
        and drives(name)
    ]


@pytest.mark.parametrize("path", _modules(), ids=lambda p: p.name)
def test_wall_clock_tests_are_marked_realtime(path):
    assert unmarked_wall_clock_tests(ast.parse(path.read_text())) == []


@pytest.mark.parametrize("path", _modules(), ids=lambda p: p.name)
def test_no_test_bounds_a_wall_clock_duration_from_above(path):
    assert upper_bounds_on_wall_time(ast.parse(path.read_text())) == []


def test_the_rules_catch_what_they_are_for():
    """Each rule flags a small example of what it forbids and passes its corrected form."""
    bad = ast.parse(
        "def test_a(x):\n"
        "    t0 = time.perf_counter()\n"
        "    assert time.perf_counter() - t0 < 0.5\n"
        "    assert 0.004 > np.median(rtts)\n"
        "    assert time.monotonic() < deadline\n"
        "def test_b():\n"
        "    run = DaemonRun()\n"
    )
    assert upper_bounds_on_wall_time(bad) == [3, 4]
    assert unmarked_wall_clock_tests(bad) == ["test_b"]
    good = ast.parse(
        "def test_a(x):\n"
        "    assert elapsed > 1.0 and len(rtts) == 3 and late.home_after < 2\n"
        "    publish_detections(bus, k, d, clock=bus.clock)\n"
        "@pytest.mark.realtime\n"
        "def test_b():\n"
        "    run = DaemonRun()\n"
    )
    assert upper_bounds_on_wall_time(good) == []
    assert unmarked_wall_clock_tests(good) == []
