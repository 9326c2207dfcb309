"""The log file of one Snakemake job.

The workflow scripts (``workflows/scripts/*.py``) run their whole body inside
:func:`job_log`: what the job prints goes to its log file, and so does the
traceback of an error, which is then raised again so that Snakemake reports the
job as failed (and prints the traceback once more on its own output). Errors that
need no traceback (:func:`one_line_error`: bad input, a full disk) are one line,
in the log and on stderr, and the job exits with status 1.
"""
from __future__ import annotations

import errno
import os
import sys
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
    line = None
    with open(path, "w") as log, redirect_stdout(log), redirect_stderr(log):
        try:
            yield log
        except Exception as exc:
            line = one_line_error(exc)
            if line is None:
                traceback.print_exc(file=log)
                log.flush()
                raise
            print(line, file=log, flush=True)
        except BaseException:
            traceback.print_exc(file=log)
            log.flush()
            raise
    if line is not None:
        print(line, file=sys.stderr, flush=True)
        raise SystemExit(1)


#: Errors of a full disk or an exhausted quota.
_NO_SPACE = (errno.ENOSPC, errno.EDQUOT)


def one_line_error(exc: BaseException) -> str | None:
    """``ddsolve: error: <what>`` for an error that needs no traceback (full disk, bad input file, an
    :class:`~ddsolve.errors.InputError` of a case that passed planning: more parts than triangles, every
    node on the Dirichlet boundary), else None."""
    from ..errors import InputError
    from .hdf5 import NoSpaceError, ResultFileError

    if isinstance(exc, (NoSpaceError, ResultFileError, InputError)):
        return f"ddsolve: error: {exc}"
    if isinstance(exc, OSError) and exc.errno in _NO_SPACE:
        where = f" writing {exc.filename}" if exc.filename else ""
        return f"ddsolve: error: no space left on device{where}"
    return None
