"""Resident memory of this process (Linux ``/proc``; ``resource`` elsewhere).

The benchmark reports, per run, the peak resident set size of the job
process (:func:`peak_rss_mb`, ``getrusage`` maxrss) and its increase over
the resident size just before the run (:func:`current_rss_mb`): the memory
the method's setup and solve added on top of the assembled problem. Memory
freed earlier but kept by the allocator can be reused without raising the
resident size, so the increase is a lower bound; each case runs in its own
job process, which keeps it close.
"""
from __future__ import annotations

import os
import resource
import sys


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far, in MiB (ru_maxrss)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    # Linux reports KiB, macOS bytes
    return peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0


def current_rss_mb() -> float:
    """Current resident set size in MiB (/proc/self/statm; the peak where /proc is missing)."""
    try:
        with open("/proc/self/statm") as fh:
            pages = int(fh.read().split()[1])
    except (OSError, ValueError, IndexError):
        return peak_rss_mb()
    return pages * os.sysconf("SC_PAGE_SIZE") / (1024.0 * 1024.0)
