"""The log file of one Snakemake job.

The workflow scripts (``workflows/scripts/*.py``) run their whole body inside
:func:`job_log`: what the job prints goes to its log file, and so does the
traceback of an error, which is then raised again so that Snakemake reports the
job as failed (and prints the traceback once more on its own output).
"""
from __future__ import annotations

import os
import traceback
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from typing import TextIO


@contextmanager
def job_log(path: str | os.PathLike) -> Iterator[TextIO]:
    """Redirect stdout and stderr to the file `path` (truncated) for the ``with`` block.

    An exception leaving the block is written to the file with its traceback and
    re-raised after stdout and stderr are restored.

    Parameters
    ----------
    path : str or os.PathLike
        The job's log file (``snakemake.log[0]``).

    Yields
    ------
    TextIO
        The open log file (for ``logging.basicConfig(stream=...)``).
    """
    with open(path, "w") as log, redirect_stdout(log), redirect_stderr(log):
        try:
            yield log
        except BaseException:
            traceback.print_exc(file=log)
            log.flush()
            raise
