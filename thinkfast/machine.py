"""What machine and which libraries a tree was compiled or a measurement ran on.

One record for every place that says where a number came from: the tree's provenance
(``machine.json`` and the ``*_version`` attributes, docs/TREE_FORMAT.md), ``thinkfast-compile
info`` and ``diff``, the benchmark JSON (``thinkfast-sim bench --json``, ``bench/*.py``). What it
records is what can make the same computation give other floating-point results: the CPU and its
features numpy dispatches to, the BLAS library and the core type it chose, the environment
variables that override them, and the library versions.
"""

from __future__ import annotations

import ctypes
import os
import platform
from importlib import metadata
from pathlib import Path
from typing import Any

# environment variables that change which kernels numpy and OpenBLAS run
KERNEL_ENV = ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES")
# version key -> (distribution names, importable module): the libraries that shape a tree
LIBRARIES: dict[str, tuple[tuple[str, ...], str]] = {
    "thinkfast": (("thinkfast",), "thinkfast"),
    "numpy": (("numpy",), "numpy"),
    "scipy": (("scipy",), "scipy"),
    "h5py": (("h5py",), "h5py"),
    "ruckig": (("ruckig",), "ruckig"),
    "pinocchio": (("pin", "pinocchio"), "pinocchio"),
    "fcl": (("python-fcl",), "fcl"),
    "trimesh": (("trimesh",), "trimesh"),
}


def machine_info() -> dict[str, Any]:
    """The machine this process runs on, as plain JSON-able values.

    Returns:
        ``cpu`` (model name from /proc/cpuinfo when present), ``cores`` (usable by this process),
        ``python``, ``numpy`` (versions), ``platform``, ``machine`` and ``system`` (as
        :mod:`platform` names them), ``blas`` (:func:`blas_info`), ``numpy_simd``
        (:func:`numpy_simd`) and ``env``: those of ``OPENBLAS_CORETYPE`` and
        ``NPY_DISABLE_CPU_FEATURES`` that are set.
    """
    import numpy as np

    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count() or 1
    return {
        "cpu": cpu_model(),
        "cores": cores,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "platform": platform.platform(),
        "machine": platform.machine(),
        "system": platform.system(),
        "blas": blas_info(),
        "numpy_simd": numpy_simd(),
        "env": {k: os.environ[k] for k in KERNEL_ENV if k in os.environ},
    }


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo), else what :mod:`platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def library_versions() -> dict[str, str]:
    """Versions of Python and of the libraries that shape a tree (:data:`LIBRARIES`), by key;
    ``"not installed"`` for one that is missing."""
    from thinkfast import __version__

    out = {"thinkfast": __version__}
    for key, (dists, module) in LIBRARIES.items():
        if key != "thinkfast":
            out[key] = _version(dists, module)
    out["python"] = platform.python_version()
    return out


def blas_info() -> dict[str, Any]:
    """The BLAS numpy uses: ``name``, ``version``, ``architecture`` (the core type OpenBLAS chose
    at load time, e.g. ``Haswell``), ``num_threads`` and ``source`` (how it was found).

    From threadpoolctl when it is installed, else numpy's build configuration
    (``np.show_config(mode="dicts")``) and, for OpenBLAS, the loaded library itself.
    """
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return _blas_from_numpy()
    for lib in threadpool_info():
        if lib.get("user_api") == "blas":
            return {
                "name": str(lib.get("internal_api", "unknown")),
                "version": str(lib.get("version")),
                "architecture": str(lib.get("architecture")),
                "num_threads": lib.get("num_threads"),
                "threading_layer": str(lib.get("threading_layer")),
                "source": "threadpoolctl",
            }
    return _blas_from_numpy()


def numpy_simd() -> dict[str, list[str]]:
    """The SIMD extensions numpy's compiled loops use on this CPU, from the public
    ``np.show_config(mode="dicts")["SIMD Extensions"]``: ``baseline`` (built in) and ``found``
    (dispatched to at run time; honours ``NPY_DISABLE_CPU_FEATURES``)."""
    simd = _numpy_config().get("SIMD Extensions", {})
    return {k: [str(x) for x in simd.get(k, [])] for k in ("baseline", "found")}


def _numpy_config() -> dict[str, Any]:
    import numpy as np

    try:
        return np.show_config(mode="dicts") or {}
    except (TypeError, ValueError):  # numpy before 1.26 only prints
        return {}


def _blas_from_numpy() -> dict[str, Any]:
    blas = _numpy_config().get("Build Dependencies", {}).get("blas", {})
    out: dict[str, Any] = {
        "name": str(blas.get("name", "unknown")),
        "version": str(blas.get("version", "unknown")),
        "architecture": "unknown",
        "num_threads": None,
        "source": "numpy.show_config",
    }
    lib = _loaded_openblas()
    if lib is not None:
        core = _openblas_call(lib, "get_corename", ctypes.c_char_p)
        threads = _openblas_call(lib, "get_num_threads", ctypes.c_int)
        out["architecture"] = core.decode() if isinstance(core, bytes) else "unknown"
        out["num_threads"] = threads
        out["source"] += " + libopenblas"
    return out


def _loaded_openblas() -> ctypes.CDLL | None:
    """The OpenBLAS shared library loaded into this process (Linux: from /proc/self/maps)."""
    import numpy  # noqa: F401  (loads its BLAS)

    try:
        maps = Path("/proc/self/maps").read_text().splitlines()
    except OSError:
        return None
    paths = sorted({ln.split()[-1] for ln in maps if "openblas" in ln.lower() and "/" in ln})
    for path in paths:
        try:
            return ctypes.CDLL(path)
        except OSError:
            continue
    return None


def _openblas_call(lib: ctypes.CDLL, name: str, restype: Any) -> Any:
    """``openblas_<name>()`` under the symbol names OpenBLAS builds use (``scipy_`` prefix,
    ``64_`` suffix for the 64-bit integer builds numpy and scipy wheels carry)."""
    for prefix in ("", "scipy_"):
        for suffix in ("", "64_"):
            fn = getattr(lib, f"{prefix}openblas_{name}{suffix}", None)
            if fn is not None:
                fn.restype, fn.argtypes = restype, []
                return fn()
    return None


def _version(dists: tuple[str, ...], module: str) -> str:
    for dist in dists:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            continue
    try:
        return str(getattr(__import__(module), "__version__", "unknown"))
    except ImportError:
        return "not installed"
