"""Temporary files removed when the process is terminated while it writes them.

The atomic writers (:func:`ddsolve.io.hdf5.atomic_target`, :func:`ddsolve.io.vtk.write_vtu`) remove
their temporary file on any exception. A SIGTERM (what ``mpiexec`` sends the other ranks when one
fails, what ``timeout`` and a batch scheduler's time limit send) or a SIGHUP kills the process
without one, and left the temporary file beside the target (a review: a complete 48 MB
``.k.<pid>.<hex>.tmp.vtu``). :func:`removed_on_termination` handles those two signals while a file is
written: it deletes the temporary files, then dies of the same signal as before.

Only where the signal's handler is the default one, and only in the main thread (Python runs signal
handlers there): a handler of the user's is left alone. The handler runs between Python bytecodes,
so a writer inside one long C call (an HDF5 or VTK write of a large file) is removed when that call
returns.
"""
from __future__ import annotations

import os
import signal
import stat
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

__all__ = ["removed_on_termination", "replace_onto", "resolved_target"]

#: The signals whose default action kills the process without an exception.
SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


def _unlink(paths: tuple[Path, ...]) -> None:
    for path in paths:
        try:
            os.unlink(path)
        except OSError:
            pass


@contextmanager
def removed_on_termination(*paths: str | os.PathLike) -> Iterator[None]:
    """While inside, SIGTERM and SIGHUP first delete ``paths``, then kill the process as before.

    Parameters
    ----------
    *paths : path-like
        Temporary files (they may not exist yet).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    files = tuple(Path(p) for p in paths)

    def handler(signum: int, frame: object) -> None:
        _unlink(files)
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)

    installed = {}
    for signum in SIGNALS:
        if signal.getsignal(signum) is signal.SIG_DFL:
            installed[signum] = signal.signal(signum, handler)
    try:
        yield
    finally:
        for signum, previous in installed.items():
            signal.signal(signum, previous)


def resolved_target(path: str | os.PathLike) -> Path:
    """The file an output at ``path`` replaces: a symbolic link's target (a review: the link itself was
    replaced by a regular file and the file it named left as it was), else ``path``."""
    path = Path(path)
    return Path(os.path.realpath(path)) if path.is_symlink() else path


def replace_onto(tmp: str | os.PathLike, target: str | os.PathLike) -> None:
    """``os.replace(tmp, target)``, the new file taking the permission bits of the file it replaces (a
    ``chmod 600`` result became 644: the temporary file's umask default)."""
    try:
        mode = os.stat(target).st_mode
    except OSError:
        mode = None
    if mode is not None and stat.S_ISREG(mode):
        os.chmod(tmp, stat.S_IMODE(mode))
    os.replace(tmp, target)
