"""Integrity of result files: validation on read, a full disk, and the workflow's checks before planning."""
from __future__ import annotations

import errno
import math
import os
import socket
import subprocess
import sys
from base64 import urlsafe_b64encode

import pytest
import yaml

from ddsolve.io import hdf5
from ddsolve.io.check import quick_check
from ddsolve.io.hdf5 import NoSpaceError, ResultFileError, read_result, validate_result, write_result
from ddsolve.io.joblog import job_log
from ddstudies import workflow as wf
from ddstudies.aggregate import CorruptResultsError, collect


class _Result:
    """The least a SolveResult offers to write_result."""

    residuals = [1.0, 0.5, 1e-7]

    def to_dict(self):
        return {"problem": "poisson", "method": "bddc", "bodies": 1, "subdomains": 2, "elements": 2,
                "converged": True, "iterations": 2, "cond": None, "reason": "ok"}


SPEC = {"problem": "poisson", "method": "bddc", "bodies": 1, "subdomains": 2, "elements": 2, "rtol": 1e-6}


@pytest.fixture
def result_file(tmp_path):
    return write_result(tmp_path / "r" / "case.h5", SPEC, _Result())


def test_whole_file_validates(result_file):
    assert quick_check(result_file) is None
    flat = validate_result(result_file)
    assert flat["iterations"] == 2 and flat["converged"] is True and math.isnan(flat["cond"])


@pytest.mark.parametrize("keep", [0, 7, 100, 1000, -1])
def test_truncated_file_is_named(result_file, keep):
    data = result_file.read_bytes()
    result_file.write_bytes(data[:keep] if keep >= 0 else data[:-1])
    assert quick_check(result_file)
    for reader in (read_result, validate_result, hdf5.read_params, hdf5.read_residuals):
        with pytest.raises(ResultFileError) as err:
            reader(result_file)
        assert str(err.value).startswith(f"{result_file}: ") and "\n" not in str(err.value)


def test_corrupt_metadata_is_named(result_file):
    data = bytearray(result_file.read_bytes())
    data[200:2000] = bytes(1800)
    result_file.write_bytes(bytes(data))
    assert quick_check(result_file) is None          # size and signature intact: only a full read finds it
    with pytest.raises(ResultFileError, match=rf"^{result_file}: corrupt"):
        validate_result(result_file)


def test_missing_and_foreign_files(tmp_path):
    with pytest.raises(ResultFileError, match="no such result file"):
        read_result(tmp_path / "nothere.h5")
    (tmp_path / "text.h5").write_text("hello")
    with pytest.raises(ResultFileError, match="not an HDF5 file"):
        validate_result(tmp_path / "text.h5")


def test_collect_names_and_moves_aside_every_corrupt_file(tmp_path):
    good = write_result(tmp_path / "a.h5", SPEC, _Result())
    bad = [write_result(tmp_path / f"{name}.h5", SPEC, _Result()) for name in ("b", "c")]
    for path in bad:
        path.write_bytes(path.read_bytes()[:500])
    with pytest.raises(CorruptResultsError) as err:
        collect([good, *bad])
    assert err.value.paths == [str(p) for p in bad] and bad[0].exists()        # reading moves nothing
    with pytest.raises(CorruptResultsError, match=rf"^{bad[0]}: corrupt result file: truncated.*1 more"):
        collect([good, *bad], quarantine=True)
    assert not bad[0].exists() and (tmp_path / "b.h5.corrupt").exists() and good.exists()


def test_full_disk_is_one_line_and_leaves_no_temporary_file(tmp_path, monkeypatch):
    real_replace = os.replace

    def full(src, dst):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(src))

    monkeypatch.setattr(hdf5.os, "replace", full)
    target = tmp_path / "case.h5"
    with pytest.raises(NoSpaceError) as err:
        write_result(target, SPEC, _Result())
    assert str(err.value) == f"no space left on device writing {target}"
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(hdf5.os, "replace", real_replace)
    monkeypatch.setenv(hdf5.FAULT_ENOSPC_ENV, "case.h5")             # the hook the workflow tests use
    with pytest.raises(NoSpaceError):
        write_result(target, SPEC, _Result())
    assert list(tmp_path.iterdir()) == []
    monkeypatch.delenv(hdf5.FAULT_ENOSPC_ENV)
    assert validate_result(write_result(target, SPEC, _Result()))["iterations"] == 2


class _FullDiskFile:
    """A file object whose disk fills up after ``room`` bytes: a short write, then ENOSPC."""

    def __init__(self, fh, room: int):
        self.fh, self.room = fh, room

    def write(self, data):
        if self.room <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), self.fh.name)
        n = self.fh.write(bytes(data[:self.room]))
        self.room -= n
        return n

    def __getattr__(self, name):
        return getattr(self.fh, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.fh.close()


def test_enospc_at_the_byte_write_is_one_line_and_keeps_the_previous_file(tmp_path, monkeypatch):
    """The HDF5 file is built in memory and written by plain file I/O: a full disk during the byte write
    (after a short write) is an ordinary OSError -> NoSpaceError, the temporary file is removed and the
    previous result stays intact."""
    target = write_result(tmp_path / "case.h5", SPEC, _Result())
    before = target.read_bytes()
    monkeypatch.setattr(hdf5, "open", lambda path, mode: _FullDiskFile(open(path, mode), 100), raising=False)
    with pytest.raises(NoSpaceError) as err:
        write_result(target, {**SPEC, "rtol": 1e-8}, _Result())
    assert str(err.value) == f"no space left on device writing {target}"
    assert isinstance(err.value.__cause__, OSError) and err.value.__cause__.errno == errno.ENOSPC
    assert sorted(p.name for p in tmp_path.iterdir()) == ["case.h5"] and target.read_bytes() == before
    with pytest.raises(SystemExit), job_log(tmp_path / "job.log"):
        write_result(tmp_path / "other.h5", SPEC, _Result())
    assert (tmp_path / "job.log").read_text().splitlines() == [
        f"ddsolve: error: no space left on device writing {tmp_path / 'other.h5'}"]
    monkeypatch.undo()
    assert validate_result(target)["reason"] == "ok"


def test_in_memory_image_reads_back_like_a_file_written_by_hdf5(tmp_path):
    """The file image of the core driver is a complete HDF5 file: its size is the superblock's end of
    file, and every attribute and dataset reads back as h5py wrote it."""
    import h5py
    import numpy as np

    target = write_result(tmp_path / "case.h5", SPEC, _Result())
    assert quick_check(target) is None
    with h5py.File(target, "r") as h5:
        assert h5.attrs["format"] == hdf5.FORMAT and h5.attrs["format_version"] == hdf5.FORMAT_VERSION
        assert dict(h5["params"].attrs) == {**SPEC}
        np.testing.assert_array_equal(h5["result/residuals"][()], _Result.residuals)
        assert list(h5["result"].attrs) == list(_Result().to_dict())       # insertion order kept
        assert math.isnan(h5["result"].attrs["cond"]) and h5["result"].attrs["reason"] == "ok"


_TMPFS_SCRIPT = """
import os, sys
import numpy as np
from ddsolve.io.hdf5 import NoSpaceError, validate_result, write_result
sys.path.insert(0, sys.argv[2])
from test_integrity import SPEC, _Result
mnt = sys.argv[1]
small = write_result(os.path.join(mnt, "small.h5"), SPEC, _Result())
assert validate_result(small)["iterations"] == 2
big = _Result()
big.u = np.arange(200_000, dtype=float)                   # 1.6 MB on a 256 KiB tmpfs
try:
    write_result(os.path.join(mnt, "big.h5"), SPEC, big, store_solution=True)
except NoSpaceError as exc:
    print(exc)
    print(sorted(os.listdir(mnt)))
    sys.exit(0)
sys.exit(3)
"""


def test_full_tmpfs_is_one_line_and_leaves_no_temporary_file(tmp_path):
    """A real full disk: a 256 KiB tmpfs in a private mount namespace (skipped where mounting is not
    permitted)."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    probe = subprocess.run(["unshare", "-rm", "sh", "-c", f"mount -t tmpfs -o size=256k tmpfs {mnt}"],
                           capture_output=True, text=True, check=False)
    if probe.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {probe.stderr.strip()[:80]}")
    script = tmp_path / "tmpfs_write.py"
    script.write_text(_TMPFS_SCRIPT)
    proc = subprocess.run(["unshare", "-rm", "sh", "-c",
                           f'mount -t tmpfs -o size=256k tmpfs {mnt} && exec "$0" "$@"',
                           sys.executable, str(script), str(mnt), os.path.dirname(__file__)],
                          capture_output=True, text=True, timeout=120, check=False,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr and "HDF5" not in proc.stderr, proc.stderr
    assert proc.stdout.splitlines() == [f"no space left on device writing {mnt / 'big.h5'}", "['small.h5']"]


def test_any_error_removes_the_temporary_file(tmp_path):
    with pytest.raises(RuntimeError):
        with hdf5.atomic_target(tmp_path / "x.csv") as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("body, line, printed", [
    ("import errno\n    print('working')\n    raise OSError(errno.ENOSPC, 'No space left on device', 'out/x.h5')",
     "ddsolve: error: no space left on device writing out/x.h5", ["working"]),
    # a case that passed planning and is refused by the solver (more parts than triangles, every node on the
    # Dirichlet boundary) failed its job with a full traceback, where docs/studies.md promises one line (a review,
    # 2026-11-28)
    ("from ddsolve.errors import InputError\n    raise InputError('parts', '500 parts for 96 triangles')",
     "ddsolve: error: parts: 500 parts for 96 triangles", []),
])
def test_job_log_turns_an_expected_error_into_one_line(tmp_path, body, line, printed):
    """A full disk and an input error: one line on stderr and in the log, exit status 1, no traceback."""
    log = tmp_path / "job.log"
    code = f"from ddsolve.io.joblog import job_log\nwith job_log({str(log)!r}):\n    {body}\n"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 1
    assert proc.stderr.strip() == line
    assert log.read_text().splitlines() == [*printed, line]


def test_job_log_keeps_the_traceback_of_anything_else(tmp_path):
    with pytest.raises(ValueError):
        with job_log(tmp_path / "other.log"):
            raise ValueError("a bug")
    assert "Traceback" in (tmp_path / "other.log").read_text()


# --- the workflow's checks (ddstudies.workflow) ------------------------------------------------


@pytest.mark.parametrize("config, where", [
    ({"rtol": float("nan")}, "rtol"), ({"a": {"b": [1.0, float("inf")]}}, "a/b/1"),
    ({"sweeps": [{"elements": [2, -math.inf]}]}, "sweeps/0/elements/1"),
])
def test_non_finite_numbers_are_refused_naming_the_key(config, where):
    with pytest.raises(wf.ConfigError, match=rf"^invalid config: {where}: must be a finite number"):
        wf.check_finite(config)
    wf.check_finite({"rtol": 1e-6, "rho": "checkerboard:100", "methods": ["feti"]})


@pytest.mark.parametrize("spec, message", [
    ({"rho": "checkerboard:0"}, "case c: rho: checkerboard:V needs a positive finite V"),
    ({"subdomains": 2, "elemnts": 4}, "case c: elemnts: unknown field"),
    ({"problem": "contact", "method": "active-set", "f": "dostal:-3,1"}, "case c: f: contact loads must be <= 0"),
    ({"problem": "contact", "method": "active-set", "f": 0.5}, "case c: f: contact loads must be <= 0"),
    ({"subdomains": 3000, "elements": 64}, "case c: needs about"),
])
def test_cases_are_checked_before_any_job(spec, message):
    with pytest.raises(wf.ConfigError, match=rf"^invalid config: {message}"):
        wf.check_cases([("c", spec)])


def test_case_sizes_give_the_resources():
    sizes = wf.check_cases([("small", {"subdomains": 2, "elements": 4}), ("big", {"subdomains": 16, "elements": 32})])
    assert wf.case_mem_mb(sizes["small"]) == 500            # the floor
    assert wf.case_mem_mb(sizes["big"]) > wf.case_mem_mb(sizes["small"])
    assert wf.case_mem_mb(sizes["big"]) >= 1.5 * sizes["big"].memory_bytes / 2**20
    assert wf.case_runtime(sizes["small"]) == 15
    with pytest.raises(wf.ConfigError, match=r"more than max_memory \(1 MiB\)"):
        wf.check_cases([("small", {"subdomains": 2, "elements": 4})], max_memory="1M")


def _study(tmp_path):
    paths = [write_result(tmp_path / "results" / f"{m}.h5", SPEC, _Result()) for m in ("a", "b")]
    paths = [os.path.relpath(p, tmp_path) for p in paths]
    (tmp_path / "results" / "summary.csv").write_text("x,file\n" + "".join(f"1,{p}\n" for p in paths))
    (tmp_path / "report.md").write_text("table")
    wf.write_manifest([*paths, "results/summary.csv"], tmp_path / "results" / "summary.sha256")
    return paths


def test_check_results_moves_truncated_files_aside_and_drops_their_consumers(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    a, b = _study(tmp_path)
    args = ("results/summary.csv", ["report.md"])
    assert wf.check_results([a, b], *args, manifest="results/summary.sha256") == []    # all fine: nothing
    with open(b, "r+b") as stream:
        stream.truncate(1000)
    lines = []
    removed = wf.check_results([a, b], *args, manifest="results/summary.sha256", log=lines.append)
    assert removed == [b, "results/summary.csv", "results/summary.sha256", "report.md"]
    assert os.path.exists(b + ".corrupt") and os.path.exists(a) and "truncated" in lines[0]


def test_check_results_finds_rot_by_checksum_and_deleted_results(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    a, b = _study(tmp_path)
    stat = os.stat(a)
    data = bytearray(open(a, "rb").read())
    data[-40] ^= 0xFF
    open(a, "wb").write(bytes(data))
    os.utime(a, ns=(stat.st_atime_ns, stat.st_mtime_ns - 10**9))
    assert wf.check_results([a, b], "results/summary.csv", ["report.md"], manifest="results/summary.sha256")[0] == a
    assert not os.path.exists("report.md")
    a, b = _study(tmp_path)
    os.unlink(b)                                  # deleted: no manifest needed, the summary names it
    os.unlink("results/summary.sha256")
    assert wf.check_results([a, b], "results/summary.csv", ["report.md"]) == ["results/summary.csv", "report.md"]


def test_a_valid_result_rewritten_after_the_summary_makes_it_stale(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    a, b = _study(tmp_path)
    os.utime("results/summary.sha256", (1, 1))
    write_result(b, {**SPEC, "rtol": 1e-8}, _Result())           # a rerun with another rtol
    assert wf.check_results([a, b], "results/summary.csv", ["report.md"],
                            manifest="results/summary.sha256") == ["results/summary.csv", "results/summary.sha256",
                                                                   "report.md"]
    assert os.path.exists(b)


def test_integral_floats_become_ints_and_nothing_else_changes():
    config = {"gamma": 1.0, "rtol": 1.0e-6, "cond": True, "subdomains": [2.0, 3], "problems": {"p": {"maxh": 0.5}}}
    assert wf.canonical_numbers(config) is config
    assert config == {"gamma": 1, "rtol": 1.0e-6, "cond": True, "subdomains": [2, 3], "problems": {"p": {"maxh": 0.5}}}
    assert type(config["gamma"]) is int and type(config["subdomains"][0]) is int and config["cond"] is True


def test_a_summary_truncated_in_place_is_rebuilt(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    a, b = _study(tmp_path)
    stat = os.stat("results/summary.csv")
    with open("results/summary.csv", "r+b") as stream:
        stream.truncate(8)                                     # one row lost, its time kept
    os.utime("results/summary.csv", ns=(stat.st_atime_ns, stat.st_mtime_ns))
    lines = []
    assert wf.check_results([a, b], "results/summary.csv", ["report.md"], manifest="results/summary.sha256",
                            log=lines.append) == ["results/summary.csv", "results/summary.sha256", "report.md"]
    assert "differs from the SHA-256" in lines[0] and os.path.exists(a) and os.path.exists(b)


def test_release_complete_keeps_valid_results_of_a_killed_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    a, b = _study(tmp_path)
    os.makedirs(".snakemake/incomplete")
    for path in (a, b, "results/missing.h5"):
        open(f".snakemake/incomplete/{urlsafe_b64encode(path.encode()).decode()}", "w").close()
    with open(b, "r+b") as stream:
        stream.truncate(100)
    assert wf.release_complete([a, b, "results/missing.h5"]) == [a]
    assert os.listdir(".snakemake/incomplete") == [] and os.path.exists(b + ".corrupt")


def test_stale_lock_of_a_dead_process_is_released(tmp_path):
    locks = tmp_path / ".snakemake" / "locks"
    locks.mkdir(parents=True)
    (locks / "0.input.lock").write_text("x")
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    owner = tmp_path / ".snakemake" / wf.OWNER_FILE
    owner.write_text(f"{socket.gethostname()} {os.getpid()}\n")          # alive: kept
    assert not wf.release_stale_lock(tmp_path / ".snakemake") and (locks / "0.input.lock").exists()
    owner.write_text(f"another-host {dead.pid}\n")                        # elsewhere: kept
    assert not wf.release_stale_lock(tmp_path / ".snakemake")
    # a dead run whose jobs ran on a cluster: they outlive it, a new run would compute their cases beside them
    # (a review on SLURM); the lock is kept and the message says what to do
    owner.write_text(f"{socket.gethostname()} {dead.pid} remote\n")
    said = []
    assert not wf.release_stale_lock(tmp_path / ".snakemake", log=said.append)
    assert (locks / "0.input.lock").exists() and "scancel" in said[0] and "snakemake --unlock" in said[0]
    owner.write_text(f"{socket.gethostname()} {dead.pid}\n")
    assert wf.release_stale_lock(tmp_path / ".snakemake") and not (locks / "0.input.lock").exists()


def test_the_owner_records_a_remote_run(tmp_path):
    wf.record_lock_owner(tmp_path, remote=True)
    host, pid, flag = (tmp_path / wf.OWNER_FILE).read_text().split()
    assert (host, int(pid), flag) == (socket.gethostname(), os.getpid(), "remote")
    wf.record_lock_owner(tmp_path)
    assert len((tmp_path / wf.OWNER_FILE).read_text().split()) == 2


def test_stale_temporary_files_are_removed(tmp_path):
    (tmp_path / "s" / "m").mkdir(parents=True)
    (tmp_path / "s" / "m" / ".Ns2_m2.h5.123.abcd1234.tmp").write_bytes(b"x")
    (tmp_path / "s" / "m" / "Ns2_m2.h5").write_bytes(b"x")
    assert wf.remove_stale_tmp(tmp_path) == [str(tmp_path / "s" / "m" / ".Ns2_m2.h5.123.abcd1234.tmp")]
    assert os.listdir(tmp_path / "s" / "m") == ["Ns2_m2.h5"]


def test_strict_yaml_refuses_a_key_twice_but_keeps_merge_keys():
    """A key written twice was read as the last one silently; the strict loader refuses it. Its first version
    also refused YAML merge keys (`<<: *anchor`), which are valid and override as YAML says (a review,
    2026-11-28)."""
    from ddstudies.workflow import ConfigError, load_yaml_strict

    text = "base: &b {rtol: 1.0e-6, maxiter: 9}\nx:\n  <<: *b\n  maxiter: 5\n"
    assert load_yaml_strict(text) == yaml.safe_load(text) == {"base": {"rtol": 1e-6, "maxiter": 9},
                                                              "x": {"rtol": 1e-6, "maxiter": 5}}
    with pytest.raises(ConfigError, match=r"key 'methods' appears twice in one mapping \(lines 2 and 4\)"):
        load_yaml_strict("study: s\nmethods: [feti]\nrtol: 1.0e-6\nmethods: [bddc]\n")
