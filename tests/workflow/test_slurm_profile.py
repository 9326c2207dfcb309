"""The SLURM profile (profiles/slurm): a dry run always; a real single-node cluster when one can be started.

The real run starts SLURM with tools/slurm-local.sh (Debian's slurm-wlm and munge, as root),
runs a tiny Poisson study through the profile (every job submitted with sbatch by
snakemake-executor-plugin-slurm), checks the outputs and stops the daemons it started.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys

import pytest
from conftest import ROOT, copy_workflow

pytest.importorskip("snakemake")

TINY = "study: slurm_tiny\nsubdomains: [2]\nelements: [2]\nmethods: [bddc]\ncond: false\ncheck: false\n"
ARGS = ("--profile", "profiles/slurm", "--configfile", "config/poisson.yaml", "tiny.yaml")
# the plugin first asks after init seconds, then 10 s later each time a job has not finished: with the
# profile's 5 s a job of about 6 s took 20 s (a 70 s test, nearly all waiting); 1 s makes it 11 s
FAST_STATUS = ("--slurm-init-seconds-before-status-checks", "1")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), str(ROOT / "studies"), env.get("PYTHONPATH")]))
    env.setdefault("OMP_NUM_THREADS", "1")
    return env


def snakemake(wd, *args, timeout=300):
    return subprocess.run([sys.executable, "-m", "snakemake", *args], cwd=wd, env=_env(), capture_output=True,
                          text=True, timeout=timeout)


@pytest.fixture
def workdir(tmp_path):
    wd = copy_workflow(tmp_path)
    shutil.copytree(ROOT / "profiles", wd / "profiles")
    (wd / "tiny.yaml").write_text(TINY)
    return wd


def test_profiles_declare_the_defaults():
    import yaml

    for name in ("local", "slurm"):
        profile = yaml.safe_load((ROOT / "profiles" / name / "config.yaml").read_text())
        assert profile["rerun-incomplete"] is True
        assert {"mem_mb", "runtime", "tasks"} <= set(profile["default-resources"])
    slurm = yaml.safe_load((ROOT / "profiles" / "slurm" / "config.yaml").read_text())
    assert slurm["executor"] == "slurm"
    # the plugin reads cpus_per_task before threads: a default would cap every rule's threads (a review)
    assert "cpus_per_task" not in slurm["default-resources"]


def test_dry_run_with_the_slurm_profile(workdir):
    proc = snakemake(workdir, "-n", *ARGS)
    text = proc.stdout + proc.stderr
    assert proc.returncode == 0, text
    counts = {rule: int(n) for rule, n in re.findall(r"^(\w+)\s+(\d+)\s*$", text, flags=re.MULTILINE)}
    assert counts == {"solve_case": 1, "aggregate": 1, "table": 1, "all": 1, "total": 4}    # cond: false: no plot
    solve = text[text.index("rule solve_case:"):]
    resources = re.search(r"resources: (.*)", solve).group(1)
    assert "mem_mb=500" in resources and "runtime=15" in resources and "tasks=1" in resources


def _cluster_missing() -> str | None:
    for tool in ("slurmctld", "slurmd", "munged", "sbatch", "squeue"):
        if shutil.which(tool) is None and not os.path.exists(f"/usr/sbin/{tool}"):
            return f"{tool} not installed (apt-get install slurm-wlm munge)"
    if os.geteuid() != 0:
        return "tools/slurm-local.sh start needs root"
    return None


@pytest.fixture(scope="module")
def cluster():
    """A single-node SLURM cluster (tools/slurm-local.sh), started once for the module (a start right after a
    stop could hang for minutes); stopped afterwards if this fixture started it.

    The node must have the machine's processors: ``nproc`` reads OMP_NUM_THREADS, and a test process that had
    set it to 1 (ddstudies.ngsolve_bench does) got a 1-CPU node on which a 2-task job pended forever
    (PartitionConfig). The start runs with OMP_NUM_THREADS=1 to keep that covered, and a running cluster of
    another size (left by an interrupted run) is restarted."""
    reason = _cluster_missing()
    if reason:
        pytest.skip(f"no local SLURM cluster: {reason}")
    script = str(ROOT / "tools" / "slurm-local.sh")
    running = subprocess.run(["sinfo", "-h", "-o", "%t"], capture_output=True, text=True, timeout=30)
    already = bool(running.returncode == 0 and re.search(r"^(idle|mix|alloc)", running.stdout, re.MULTILINE))
    if already and _node_cpus() != os.cpu_count():
        subprocess.run([script, "stop"], capture_output=True, timeout=60)
        already = False
    if not already:
        start = subprocess.run([script, "start"], capture_output=True, text=True, timeout=120,
                               env=dict(os.environ, OMP_NUM_THREADS="1"))
        if start.returncode != 0:
            pytest.skip(f"tools/slurm-local.sh start failed: {start.stderr.strip()[-300:]}")
    try:
        assert _node_cpus() == os.cpu_count()
        yield
    finally:
        if not already:
            subprocess.run([script, "stop"], capture_output=True, timeout=60)


def _node_cpus() -> int | None:
    """CPUTot of the local cluster's node (None if scontrol does not say)."""
    node = subprocess.run(["scontrol", "show", "node"], capture_output=True, text=True, timeout=30).stdout
    match = re.search(r"\bCPUTot=(\d+)\b", node)
    return int(match.group(1)) if match else None


@pytest.mark.slow
def test_tiny_study_on_a_local_slurm_cluster(workdir, cluster):
    import pandas as pd

    proc = snakemake(workdir, *ARGS, *FAST_STATUS, timeout=400)
    text = proc.stdout + proc.stderr
    assert proc.returncode == 0, text
    # the solve went through sbatch; aggregate and table are local rules (a queue wait for a 1 s job)
    assert len(re.findall(r"has been submitted with SLURM jobid", text)) == 1, text
    assert re.search(r"^localrule (aggregate|table):", text, re.MULTILINE), text
    df = pd.read_csv(workdir / "results" / "slurm_tiny" / "summary.csv")
    assert len(df) == 1 and df["converged"].all() and df["method"].tolist() == ["bddc"]
    assert "BDDC iter" in (workdir / "reports" / "slurm_tiny" / "table.md").read_text()
    again = snakemake(workdir, "-n", *ARGS)
    assert "Nothing to be done" in again.stdout + again.stderr


# FETI-DP only (the contact case's launch is the same command; it runs in tests/workflow/test_mpi_study.py)
TINY_MPI = "kind: mpi\nstudy: tiny_mpi\nmethod: fetidp\nsubdomains: 4\nelements: 4\nranks: [1, 2]\nrepeats: 1\n"


@pytest.mark.slow
@pytest.mark.parametrize("launcher", ["mpiexec", "srun --mpi=pmi2"])
def test_tiny_mpi_study_on_a_local_slurm_cluster(workdir, cluster, launcher):
    """P = 1 was refused by the plugin ("'tasks' must be greater than 1"), P = 2 asked for 2 x 2 cpus (pending
    forever on a 2-core node), and a bare srun ran P singleton solves (a review)."""
    if launcher.startswith("srun"):
        plugins = subprocess.run(["srun", "--mpi=list"], capture_output=True, text=True, timeout=30)
        if "pmi2" not in plugins.stdout + plugins.stderr:
            pytest.skip("this SLURM has no pmi2 plugin (srun --mpi=list)")
    (workdir / "tiny_mpi.yaml").write_text(TINY_MPI + f"launcher: {launcher}\n")
    proc = snakemake(workdir, "--profile", "profiles/slurm", "--configfile", "tiny_mpi.yaml", *FAST_STATUS,
                     timeout=400)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    one, two = (json.loads((workdir / "results" / "tiny_mpi" / "fetidp" / f"P{P}.json").read_text()) for P in (1, 2))
    assert (one["n_ranks"], two["n_ranks"]) == (1, 2)
    assert two["comm"]["messages_per_iteration"] > 0 and two["iterations"] == one["iterations"]
    assert "fetidp, 225 dofs, 16 subdomains" in (workdir / "reports" / "tiny_mpi" / "mpi.md").read_text()


@pytest.mark.slow
def test_a_timed_case_runs_on_the_cores_slurm_gave(workdir, cluster):
    """The timed cases take all of --cores (scaling_threads): inside a SLURM job that was the node's count, more
    than the job's allocation ("srun: More processors requested than permitted"; a review ran the quick
    reproduction through the profile: it stopped at the first scaling case)."""
    (workdir / "tiny_scaling.yaml").write_text(
        "kind: scaling\nstudy: slurm_scaling\nsubdomains: 2\nelements: [2, 4]\nmethods: [active-set]\nrepeats: 1\n"
        "profile: {elements: 4}\n")
    proc = snakemake(workdir, "--profile", "profiles/slurm", "--configfile", "config/scaling.yaml", "tiny_scaling.yaml",
                     *FAST_STATUS, timeout=400)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert len(re.findall(r"has been submitted with SLURM jobid", proc.stdout + proc.stderr)) == 3   # two cases, the profile
    assert (workdir / "reports" / "slurm_scaling" / "scaling.md").is_file()
