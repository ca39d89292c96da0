"""Peak memory of the code a ``with`` block runs (``peak_memory`` in the eval config): :class:`PeakMemory`.

``rss`` (default, Linux) returns the free heap to the OS (glibc ``malloc_trim(0)``, so memory the method reuses
from earlier methods counts as its own), resets the process's RSS high-water mark (``/proc/self/clear_refs``, value
5) before the method and reads ``VmHWM`` after it: the peak resident memory while the method ran, reported as the
increase over the resident memory when it started (``peak_memory_mb``) and as the absolute peak (``peak_rss_mb``).
Every allocation counts (numpy, numba, torch, ONNX Runtime), timing is unaffected. The trajectory evaluator reads
every session's streams and floor plan before the first method, so no method pays for reading the data; what the
methods load or build on first use and share (imported code, JIT-compiled kernels, map geometry per floor and
attitude per session in ``RunInputs.cache``) is counted in the first method that needs it. ``tracemalloc`` (the
fallback where /proc is not writable) counts Python and numpy allocations only and slows Python-heavy methods
(their real-time factor then includes that). ``none``: not measured.
"""

from __future__ import annotations

import logging
import re
import tracemalloc
from pathlib import Path

log = logging.getLogger("blenav.eval")

_CLEAR_REFS = Path("/proc/self/clear_refs")
_STATUS = Path("/proc/self/status")


def _status_kb(field: str) -> int:
    m = re.search(rf"^{field}:\s+(\d+)\s+kB", _STATUS.read_text(), re.M)
    if m is None:
        raise OSError(f"{_STATUS} has no {field}")
    return int(m.group(1))


def _malloc_trim() -> None:
    """glibc's malloc_trim(0): return free heap memory to the OS (a no-op where there is no glibc)."""
    import ctypes
    import gc

    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def rss_probe_available() -> bool:
    try:
        _CLEAR_REFS.write_text("5")
        _status_kb("VmHWM")
        return True
    except OSError:
        return False


class PeakMemory:
    """Context manager measuring the peak memory of the code it wraps; ``result()`` is
    ``{"peak_memory_mb", "peak_rss_mb" (rss only), "how"}`` or None (``how='none'``)."""

    def __init__(self, how: str | None = "rss"):
        how = str(how or "none")
        if how not in ("rss", "tracemalloc", "none"):
            raise ValueError(f"peak_memory must be rss, tracemalloc or none, got {how!r}")
        if how == "rss" and not rss_probe_available():
            log.warning("peak_memory=rss needs a writable /proc/self/clear_refs (Linux): using tracemalloc")
            how = "tracemalloc"
        self.how, self._res, self._started = how, None, False

    def __enter__(self):
        if self.how == "rss":
            _malloc_trim()  # freed heap pages back to the OS, so memory the method reuses is counted as its own
            _CLEAR_REFS.write_text("5")  # VmHWM := VmRSS
            self._base = _status_kb("VmRSS")
        elif self.how == "tracemalloc":
            self._started = not tracemalloc.is_tracing()
            if self._started:
                tracemalloc.start()
            tracemalloc.reset_peak()
            self._base = tracemalloc.get_traced_memory()[0]
        return self

    def __exit__(self, *exc):
        if self.how == "rss":
            peak = _status_kb("VmHWM")
            self._res = {"peak_memory_mb": max(peak - self._base, 0) / 1024.0, "peak_rss_mb": peak / 1024.0,
                         "how": "rss: peak resident memory while the method ran (glibc malloc_trim, then VmHWM after clear_refs) minus "
                                "the resident memory when it started"}
        elif self.how == "tracemalloc":
            peak = tracemalloc.get_traced_memory()[1]
            if self._started:
                tracemalloc.stop()
            self._res = {"peak_memory_mb": max(peak - self._base, 0) / 2**20,
                         "how": "tracemalloc: peak of Python/numpy allocations while the method ran"}
        return False

    def result(self) -> dict | None:
        return self._res
