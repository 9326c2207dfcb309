"""Integrity of a study's files, for the Snakemake workflow (``workflows/``): result files validated
before planning (a corrupt one moved aside, :func:`check_results`), the manifest of what a summary
aggregated (:func:`write_manifest`), atomic text outputs, stale temporary files and the lock of a
killed run. Re-exported by :mod:`ddstudies.workflow`; like it, this module imports neither numpy nor
pandas at import time.
"""
from __future__ import annotations

import os
from typing import Any, Iterable, Mapping

__all__ = ["quarantine", "read_job_results", "with_html_twins", "rebuild_below_missing", "sha256", "write_text",
           "write_manifest", "read_manifest", "summarized_files", "check_results", "release_complete",
           "record_lock_owner", "release_stale_lock", "remove_stale_tmp", "OWNER_FILE"]


def quarantine(path: str | os.PathLike, why: str) -> str:
    """Move a corrupt result aside to ``<path>.corrupt`` (so that the next run recomputes it); the new path."""
    target = f"{os.fspath(path)}.corrupt"
    os.replace(path, target)
    return target


def read_job_results(paths: Iterable[str | os.PathLike]) -> list[Any]:
    """The JSON (``.json``) or CSV (``.csv``, as a DataFrame) results of a study's jobs, each checked.

    The HDF5 results are validated by :func:`ddstudies.aggregate.collect`; the JSON and CSV ones of the
    mpi, stress and unstructured studies were read as they were: a truncated JSON gave a
    ``JSONDecodeError`` traceback on every rerun, and a CSV cut to its header dropped its rows from the
    report without a word (a review). A file that does not parse, is empty, or (CSV) has no row is moved
    aside to ``<file>.corrupt`` and the error names it; the next run recomputes it.

    Raises
    ------
    ddstudies.aggregate.CorruptResultsError
        ``<path>: corrupt result file: ...; moved aside to <file>.corrupt, the next run recomputes them``.
    """
    import json
    from pathlib import Path

    import pandas as pd

    from ddsolve.io.hdf5 import ResultFileError

    from .aggregate import CorruptResultsError

    out, errors = [], []
    for path in paths:
        try:
            if os.fspath(path).endswith(".csv"):
                value = pd.read_csv(path)
                empty = value.empty
            else:
                value = json.loads(Path(path).read_text())
                empty = not value
        except (OSError, UnicodeDecodeError, ValueError, pd.errors.ParserError) as exc:
            errors.append(ResultFileError(path, f"{type(exc).__name__}: {exc}"[:200]))
            continue
        if empty:
            errors.append(ResultFileError(path, "no result in it"))
            continue
        out.append(value)
    if errors:
        for err in errors:
            if os.path.exists(err.path):
                quarantine(err.path, err.what)
        raise CorruptResultsError(errors, moved=True)
    return out


def with_html_twins(outputs: Iterable[str | os.PathLike]) -> list[str]:
    """``outputs`` and, for each ``.md`` or ``.csv`` among them, its HTML copy for the report (``<stem>.html``,
    :func:`ddstudies.report.html.write_twins`): a stale copy outlived its table when a result was deleted
    (a review)."""
    out: list[str] = []
    for path in map(os.fspath, outputs):
        out.append(path)
        stem, ext = os.path.splitext(path)
        if ext in (".md", ".csv") and stem + ".html" not in out:
            out.append(stem + ".html")
    return out


def rebuild_below_missing(paths: Iterable[str | os.PathLike], outputs: Iterable[str | os.PathLike],
                          log=None) -> list[str]:
    """Remove ``outputs`` when one of the job results ``paths`` they are made from is missing; the removed.

    Snakemake does not recreate a missing intermediate file whose consumers are up to date: a deleted
    ``P2.json`` (mpi), ``cases/<series>.json`` (stress) or ``r1.csv`` (unstructured) stayed missing
    ("Nothing to be done", a review). With the outputs gone, the run recomputes the result and them
    (the HDF5 studies do the same through :func:`check_results`).
    """
    missing = [os.fspath(p) for p in paths if not os.path.exists(p)]
    removed = []
    if missing:
        for out in with_html_twins(outputs):
            if os.path.exists(out):
                os.remove(out)
                removed.append(os.fspath(out))
    if removed and log is not None:
        log(f"{missing[0]} is missing{f' (and {len(missing) - 1} more)' if len(missing) > 1 else ''}: removed "
            f"{', '.join(removed)} to rebuild them")
    return removed


def sha256(path: str | os.PathLike) -> str:
    """The SHA-256 of a file (hex)."""
    import hashlib

    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` atomically (a temporary file beside it, then a rename): a report, table or
    summary is never seen half written (a review found the table and summary scripts writing in place)."""
    from pathlib import Path

    from ddsolve.io.hdf5 import atomic_target

    with atomic_target(Path(path)) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_manifest(paths: Iterable[str | os.PathLike], manifest: str | os.PathLike) -> None:
    """Write ``<sha256>  <path>`` of each file (the ``sha256sum`` format), atomically."""
    write_text(manifest, "".join(f"{sha256(path)}  {os.fspath(path)}\n" for path in paths))


def read_manifest(manifest: str | os.PathLike) -> dict[str, str]:
    """``{path: sha256}`` of a manifest written by :func:`write_manifest` (``{}`` if unreadable)."""
    out = {}
    try:
        with open(manifest) as stream:
            for line in stream:
                digest, sep, path = line.rstrip("\n").partition("  ")
                if sep and len(digest) == 64:
                    out[path] = digest
    except (OSError, UnicodeDecodeError):
        return {}
    return out


def summarized_files(summary: str | os.PathLike) -> list[str]:
    """The result files a summary CSV was built from (its ``file`` column; ``[]`` if unreadable)."""
    import csv

    try:
        with open(summary, newline="") as stream:
            return [row["file"] for row in csv.DictReader(stream) if row.get("file")]
    except (OSError, csv.Error, UnicodeDecodeError):
        return []


def _changed_since_aggregated(path, recorded: Mapping[str, str], manifest) -> tuple[str | None, bool]:
    """(what is wrong, rewritten) of a result that the manifest records.

    Unchanged since the manifest was written (not newer): its SHA-256 must match
    (else it rotted or was overwritten in place, keeping its time). Newer: a job
    rewrote it after the aggregation (a changed parameter, an interrupted rerun),
    so it is read whole instead (:func:`ddsolve.io.hdf5.validate_result`), and the
    summary made before it is stale (``rewritten``).
    """
    key = os.fspath(path)
    if key not in recorded:
        return None, False
    if os.path.getmtime(path) <= os.path.getmtime(manifest):
        if sha256(path) != recorded[key]:
            return "its SHA-256 differs from the one recorded when it was aggregated", False
        return None, False
    from ddsolve.io.hdf5 import ResultFileError, validate_result

    try:
        validate_result(path)
    except ResultFileError as err:
        return err.what, False
    return None, sha256(path) != recorded[key]


def check_results(paths: Iterable[str | os.PathLike], summary: str | os.PathLike | None = None,
                  consumers: Iterable[str | os.PathLike] = (), log=None,
                  manifest: str | os.PathLike | None = None) -> list[str]:
    """Quick-check every existing result file, move the bad ones aside; rebuild what was made from them.

    A truncated, empty or non-HDF5 file (:func:`ddsolve.io.check.quick_check`),
    or one whose SHA-256 differs from the one in ``manifest`` (written by the
    aggregate step from the files it validated), would count as done under its
    output name: it is moved to ``<path>.corrupt``.
    Snakemake does not recreate a missing intermediate file whose consumers are
    up to date, so when a result that ``summary`` was built from (its ``file``
    column) is missing now (moved aside here, or deleted), the summary and its
    ``consumers`` (the reports made from it) are removed: the run then recomputes
    the result and everything after it. So are they when a result is newer than
    the manifest and differs from it (a job rewrote it after the aggregation), and when the summary itself
    differs from the SHA-256 the manifest records for it (truncated or edited, its time kept or not;
    manifests written before the summary was recorded skip this). (A new case, never in the summary, needs
    nothing: Snakemake's input rerun-trigger sees the changed inputs.)

    Returns
    -------
    list of str
        The files removed (the corrupt results moved aside, then the consumers).
    """
    from ddsolve.io.check import quick_check

    removed, rewritten = [], []
    recorded = read_manifest(manifest) if manifest is not None else {}
    for path in paths:
        if not os.path.exists(path):
            continue
        problem = quick_check(path)
        if not problem:
            problem, changed = _changed_since_aggregated(path, recorded, manifest)
            if changed:
                rewritten.append(os.fspath(path))
        if problem:
            target = quarantine(path, problem)
            removed.append(os.fspath(path))
            if log is not None:
                log(f"ddsolve: corrupt result {os.fspath(path)} ({problem}): moved to {target}; it is recomputed")
    if summary is None or not os.path.exists(summary):
        return removed
    summary_key = os.fspath(summary)
    altered = summary_key in recorded and sha256(summary) != recorded[summary_key]
    results = [path for path in recorded if path != summary_key] or summarized_files(summary)
    gone = [path for path in results if not os.path.exists(path)]
    if gone or rewritten or altered:
        for consumer in [summary, *([manifest] if manifest else []), *with_html_twins(consumers)]:
            if os.path.exists(consumer):
                os.unlink(consumer)
                removed.append(os.fspath(consumer))
        if log is not None:
            what = (f"{len(gone)} result(s) of {summary_key} are missing ({gone[0]}"
                    f"{', ...' if len(gone) > 1 else ''})" if gone else
                    f"{len(rewritten)} result(s) were rewritten after {summary_key} ({rewritten[0]}"
                    f"{', ...' if len(rewritten) > 1 else ''})" if rewritten else
                    f"{summary_key} differs from the SHA-256 recorded when it was written")
            log(f"ddsolve: {what}: removed it and the reports made from it; all are rebuilt")
    return removed


def release_complete(paths: Iterable[str | os.PathLike], snakemake_dir: str | os.PathLike = ".snakemake",
                     log=None) -> list[str]:
    """Clear Snakemake's "incomplete" marks of results that are complete; the paths released.

    Snakemake marks a job's outputs incomplete when the job starts and clears the
    mark when it has recorded the job as finished; a run killed in between leaves a
    finished file marked, and the next run refuses to start (or, with
    ``--rerun-incomplete``, recomputes it). Our result files are written
    atomically (:func:`ddsolve.io.hdf5.atomic_target`), so a file under its final
    name is complete: a marked file that reads whole
    (:func:`ddsolve.io.hdf5.validate_result`) is kept and its mark cleared; a
    marked file that does not is moved aside (``<path>.corrupt``) and recomputed;
    a marked path with no file is only unmarked (its job runs again anyway).
    The marks are the files ``<snakemake_dir>/incomplete/<urlsafe base64 of the
    path>`` of Snakemake's file persistence backend (Snakemake 8, 9).
    """
    from base64 import urlsafe_b64encode

    folder = os.path.join(snakemake_dir, "incomplete")
    if not os.path.isdir(folder):
        return []
    released = []
    for path in paths:
        key = urlsafe_b64encode(os.fspath(path).encode()).decode()
        mark = os.path.join(folder, key)
        if len(key) >= 255 or not os.path.isfile(mark):
            continue
        if os.path.exists(path):
            from ddsolve.io.hdf5 import ResultFileError, validate_result

            try:
                validate_result(path)
                released.append(os.fspath(path))
                if log is not None:
                    log(f"ddsolve: {os.fspath(path)} was marked incomplete by an interrupted run; it is complete "
                        f"(written atomically, reads whole): kept")
            except ResultFileError as err:
                target = quarantine(path, err.what)
                if log is not None:
                    log(f"ddsolve: corrupt result {os.fspath(path)} ({err.what}): moved to {target}; "
                        f"it is recomputed")
        os.unlink(mark)
    return released


#: The file (under .snakemake/) naming the host and process of the run that holds the lock.
OWNER_FILE = "ddsolve-lock-owner"


def record_lock_owner(snakemake_dir: str | os.PathLike = ".snakemake", remote: bool = False) -> None:
    """Write ``<host> <pid>`` of this (locked, running) Snakemake process, and ``remote`` when its jobs run
    elsewhere (a cluster executor: ``not workflow.local_exec``); called from ``onstart``."""
    import socket

    os.makedirs(snakemake_dir, exist_ok=True)
    with open(os.path.join(snakemake_dir, OWNER_FILE), "w") as stream:
        stream.write(f"{socket.gethostname()} {os.getpid()}{' remote' if remote else ''}\n")


def release_stale_lock(snakemake_dir: str | os.PathLike = ".snakemake", log=None) -> bool:
    """Remove the locks that a killed run on this host left (its process is gone); True if removed.

    Snakemake locks the working directory while it runs and never unlocks it when
    killed (SIGKILL, a power loss): the next run stops until ``--unlock``. The
    owner recorded by :func:`record_lock_owner` says which process held the lock;
    only when it ran on this host and no longer exists are the locks removed. Not when
    its jobs ran on a cluster (``remote``): they outlive the submitting process, and a
    new run would compute their cases again beside them (a review on SLURM); ``log``
    then says to cancel them (``squeue``, ``scancel``) and to run ``snakemake --unlock``.
    """
    import socket

    locks = os.path.join(snakemake_dir, "locks")
    owner = os.path.join(snakemake_dir, OWNER_FILE)
    try:
        names = [name for name in os.listdir(locks) if name.endswith(".lock")]
        with open(owner) as stream:
            host, pid, *flags = stream.read().split()
        pid = int(pid)
    except (OSError, ValueError):
        return False
    if not names or host != socket.gethostname():
        return False
    try:
        os.kill(pid, 0)
        return False              # alive (or not ours to signal): the lock may be real
    except ProcessLookupError:
        pass
    except PermissionError:
        return False
    if "remote" in flags:
        if log is not None:
            log(f"ddsolve: the run that locked this directory (process {pid} on {host}) is gone, but its jobs ran "
                f"on the cluster and may still be running: cancel them (squeue --me, scancel) or let them end, "
                f"then run 'snakemake --unlock' (with the same options) and start again")
        return False
    for name in names:
        try:
            os.unlink(os.path.join(locks, name))
        except FileNotFoundError:
            pass
    os.unlink(owner)
    if log is not None:
        log(f"ddsolve: removed the lock of a killed run (process {pid} on {host} is gone)")
    return True


def remove_stale_tmp(root: str | os.PathLike = "results") -> list[str]:
    """Remove the temporary files (``.<name>.<pid>.<random>.tmp``) that killed writers left under ``root``.

    Call only while no job writes there (Snakemake's ``onstart``, which runs with the
    working directory locked). Returns the removed paths.
    """
    removed = []
    for folder, _, names in os.walk(root):
        for name in names:
            if name.startswith(".") and name.endswith(".tmp"):
                path = os.path.join(folder, name)
                try:
                    os.unlink(path)
                    removed.append(path)
                except FileNotFoundError:
                    pass
    return removed
