"""Which decision kernels this process runs: the numba-compiled ones or the numpy reference.

The environment variable ``THINKFAST_KERNELS`` chooses, read once per process on the first
question: ``compiled`` (the default when numba imports) or ``numpy`` (the default, with one
warning line, when it does not). Both give the same values bit for bit (tests/test_*_jit.py);
the compiled kernels decide faster but cost their process numba's import and the loading (or,
the first time in a checkout, the compiling) of the kernels when a planner is built
(docs/BENCHMARKS.md, "Compiled decision kernels"). With ``numpy`` no thinkfast module imports
numba: the compiled modules (``*_jit.py``) are imported by the call sites only when
:func:`compiled` says so. Lives in the lowest layer that has a compiled kernel (robot).
"""

from __future__ import annotations

import os
import sys

from thinkfast.errors import ConfigError

VARIABLE = "THINKFAST_KERNELS"
CHOICES = ("compiled", "numpy")
_choice: str | None = None  # this process's choice, once asked


def compiled() -> bool:
    """Whether this process runs the compiled kernels (chosen on the first call)."""
    global _choice
    if _choice is None:
        _choice = _from_environment(os.environ.get(VARIABLE, ""))
    return _choice == "compiled"


def use(choice: str) -> str:
    """Choose the kernels of this process from now on (tests compare both in one process).

    Args:
        choice: one of :data:`CHOICES`.

    Returns:
        The choice before (as :func:`compiled` would have made it).

    Raises:
        ConfigError: an unknown choice, or ``compiled`` without numba.
    """
    global _choice
    _check(choice)
    before = "compiled" if compiled() else "numpy"
    if choice == "compiled":
        try:
            import numba  # noqa: F401
        except ImportError as exc:
            raise ConfigError("environment", VARIABLE, f"compiled needs numba ({exc})") from exc
    _choice = choice
    return before


def _from_environment(value: str) -> str:
    """The choice for the variable's ``value`` ('' when unset)."""
    value = value.strip() or "compiled"
    _check(value)
    if value == "numpy":
        return value
    try:
        import numba  # noqa: F401
    except ImportError as exc:
        print(
            f"thinkfast: numba does not import ({exc}): the numpy kernels ({VARIABLE}=numpy)",
            file=sys.stderr,
        )
        return "numpy"
    return value


def _check(value: str) -> None:
    if value not in CHOICES:
        raise ConfigError(
            "environment", VARIABLE, f"{value!r}: expected one of {', '.join(CHOICES)}"
        )
