"""What the benchmark scripts share: which machine and which code a table was measured on.

The scripts run as ``python benchmarks/bench_*.py``, so this folder is on ``sys.path``.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def git_commit() -> str:
    """The checkout's short commit, ``-dirty`` when tracked files differ from it; ``?``
    outside a git checkout."""
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "describe", "--always", "--dirty"],
                             capture_output=True, text=True, timeout=5).stdout.strip()
    except Exception:  # noqa: BLE001 - best effort only
        return "?"
    return out or "?"


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux), else what ``platform`` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "?"


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity), else ``os.cpu_count()``."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def load_average(sep: str = " / ") -> str:
    try:
        return sep.join(f"{x:.2f}" for x in os.getloadavg())
    except (AttributeError, OSError):
        return "?"


def fmt_time(s: float, digits: int = 1) -> str:
    """Seconds in µs / ms / s with ``digits`` / ``digits + 1`` / ``digits + 2`` decimals."""
    if s < 1e-3:
        return f"{s * 1e6:.{digits}f} µs"
    if s < 1.0:
        return f"{s * 1e3:.{digits + 1}f} ms"
    return f"{s:.{digits + 2}f} s"


def table(header: list[str], rows: list[list[str]]) -> str:
    """A markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def early_thread_settings() -> dict:
    """Environment for the native thread pools, set before any library loads them.

    libgomp (pycolmap/GLOMAP) spins while waiting by default; on a shared machine whose
    cores are busy that makes GLOMAP 10-30x slower (measured here: syn500 solve 0.3-0.5 s
    with passive waiting, 5-12 s spinning), so ``OMP_WAIT_POLICY=PASSIVE`` unless the user
    set a policy. ``--threads N`` also caps OpenMP and BLAS pools at N (default: the
    libraries' own defaults, i.e. all cores).
    """
    env = {}
    if "OMP_WAIT_POLICY" not in os.environ:
        os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    for k, a in enumerate(sys.argv):
        val = a.split("=", 1)[1] if a.startswith("--threads=") else (
            sys.argv[k + 1] if a == "--threads" and k + 1 < len(sys.argv) else None)
        if val:
            for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
                os.environ[var] = val
    for var in ("OMP_WAIT_POLICY", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = os.environ.get(var, "(unset)")
    return env


def json_clean(o, inf_as_text: bool = False):
    """``o`` (a benchmark's results: dicts, lists, numpy arrays and scalars) as plain JSON:
    numpy values as Python ones, ``traceback`` keys dropped, NaN as None and infinities as
    None or, with ``inf_as_text``, ``"inf"`` / ``"-inf"`` (a failed contender's ratio)."""
    import math

    import numpy as np  # here: this module is imported before any native library

    if isinstance(o, dict):
        return {str(k): json_clean(v, inf_as_text) for k, v in o.items() if k != "traceback"}
    if isinstance(o, (list, tuple)):
        return [json_clean(v, inf_as_text) for v in o]
    if isinstance(o, np.ndarray):
        return json_clean(o.tolist(), inf_as_text)
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return json_clean(o.item(), inf_as_text)
    if isinstance(o, float) and not math.isfinite(o):
        return None if math.isnan(o) or not inf_as_text else ("inf" if o > 0 else "-inf")
    return o
