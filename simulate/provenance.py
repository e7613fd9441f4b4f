"""Provenance of simulated results: software versions and JSON-safe metadata (a leaf: numpy only).

Every file ``simulate`` writes (datasets' ``meta.json``, fiber tables, fit and sweep outputs)
records the versions it ran with and its parameters through these two functions.
"""

from __future__ import annotations

import importlib.metadata
import os
import platform
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["software_versions", "jsonable", "machine"]


def software_versions() -> dict:
    """Versions of the packages a simulation result depends on."""
    import numba
    import scipy

    from gonio.version import VERSION, commit

    out = {"fabric-optics": VERSION, "commit": commit(), "python": platform.python_version(),
           "numpy": np.__version__, "scipy": scipy.__version__, "numba": numba.__version__}
    try:  # the installed version, without importing it (its import compiles a kernel)
        out["miepython"] = importlib.metadata.version("miepython")
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover - a declared dependency
        pass
    return out


def jsonable(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars/arrays to Python, non-finite floats to None, others to str."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return jsonable(obj.item())
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if obj is None or isinstance(obj, (str, int, bool)):
        return obj
    return str(obj)


def machine() -> dict[str, Any]:
    """What a measured figure was measured on: CPU model, logical CPUs, system and Python."""
    model = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": model or platform.processor() or "unknown", "cpus": os.cpu_count(),
            "system": f"{platform.system()} {platform.machine()}", "python": platform.python_version()}
