"""Snakemake script of rule mpi_case: `mpiexec -n P python -m ddsolve solve --json` (best of params.repeats
solve phases), with the load average before and after each run, and its peer measured in the same job,
the runs alternating: for P = 1 the serial solver (no mpiexec, key "serial"), for P > 1 the same command
on one rank (key "peer", the reference of the speed-up); the JSON written atomically."""

from ddsolve.io.joblog import job_log  # noqa: E402

with job_log(snakemake.log[0]) as log:  # noqa: F821
    import json
    import os
    import shlex
    import subprocess
    import sys
    from pathlib import Path

    sm = snakemake  # noqa: F821
    P = int(sm.wildcards.P)
    flags = [f"--{key}={value}" for key, value in sm.params.spec.items()]
    solve = [sys.executable, "-m", "ddsolve", "solve", *flags, "--json"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    launcher = shlex.split(sm.params.launcher)     # e.g. "srun --mpi=pmi2": a command with its options

    def run(cmd: list[str]) -> dict:
        """The JSON of one run of cmd, with the load average before and after it."""
        load_before = os.getloadavg()[0]
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
        print(" ".join(cmd), proc.stderr, sep="\n", flush=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}: {proc.stderr.strip()[-500:]}")
        result = json.loads(proc.stdout)
        result["load_average"] = [load_before, os.getloadavg()[0]]
        return result

    def fastest(*cmds: list[str]) -> list[dict]:
        """For each command, the JSON of its run with the fastest solve phase; the commands run in turn,
        params.repeats times, so that a machine whose speed drifts slows them alike."""
        best: list[dict | None] = [None] * len(cmds)
        for _ in range(sm.params.repeats):
            for k, cmd in enumerate(cmds):
                result = run(cmd)
                if best[k] is None or result["solve_seconds"] < best[k]["solve_seconds"]:
                    best[k] = result
        return best

    keys = ("solve_seconds", "iterations", "load_average")
    if P == 1:     # the serial solver (no mpiexec) in the same job: the peer of every distributed run
        best, serial = fastest([*launcher, "-n", "1", *solve], solve)
        best["serial"] = {key: serial[key] for key in keys}
    else:          # the same command on one rank in the same job: the reference of this run's speed-up
        best, peer = fastest([*launcher, "-n", str(P), *solve], [*launcher, "-n", "1", *solve])
        best["peer"] = {key: peer[key] for key in keys}
    out = Path(sm.output[0])
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(best, indent=1))
    tmp.replace(out)
