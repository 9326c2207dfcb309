"""Command line: ``ddsolve solve`` (also ``python -m ddsolve solve``).

Bad input prints one line ``ddsolve: error: <field>: <message>`` on stderr and
exits with status 2, without a traceback: malformed values, hostile scene
files (see :func:`ddsolve.spec.read_scene`), a flag that does not apply to the
chosen problem or method (see :mod:`ddsolve.spec`), and a problem whose
estimated memory or set-up time exceeds this machine
(:func:`ddsolve.limits.check_resources`, checked before anything is built).
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from typing import Any, Sequence

from .errors import InputError, OutputError
from .limits import check_resources, parse_size
from .spec import ProblemSpec

EXIT_INPUT = 2

_EPILOG = ("A flag left at its default is always accepted; a non-default value for a flag that the chosen "
           "problem or method does not use is an error (e.g. --contact middle outside multibody, "
           "--rho body-checkerboard:V for poisson, --cond with direct or contact methods, --check, --rtol, "
           "--maxiter, --scaling or --gamma with --method direct, --gamma with --scaling multiplicity, "
           "--norm/--projection outside hybrid, --parts/--maxh/--refine/--geometry with --mesh structured, "
           "--subdomains/--elements with --mesh unstructured). Scene files: a regular UTF-8 file of at most 1 MiB. "
           "Problems whose estimated memory exceeds the available memory (or --max-memory) are refused "
           "before anything is built.")


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line and exit with status 2."""

    def error(self, message: str) -> None:  # pragma: no cover - exercised through main()
        raise InputError("arguments", message)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="ddsolve", description="Substructuring domain decomposition solvers (Lee 2009).")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress to stderr")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    s = commands.add_parser("solve", help="solve one scene and report iterations, condition estimate, timings",
                            description="Solve one scene and report iterations, condition estimate, timings.",
                            epilog=_EPILOG)
    s.add_argument("scene", nargs="?", help="YAML scene file (flags override its fields)")
    # -v after the command too (ddsolve solve -v); SUPPRESS keeps a -v given before it
    s.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS, help="log progress to stderr")
    s.add_argument("--problem", help="poisson (default), multibody or contact")
    s.add_argument("--method", help="poisson: fetidp (default), feti, bddc, direct; "
                                    "multibody: feti-feti, hybrid, direct; contact: active-set, smalbe, direct")
    s.add_argument("--contact", help="multibody active area: full (case I, default) or middle (case II)")
    s.add_argument("--bodies", help="bodies per side, 1/H_b (default 1; contact: 2)")
    s.add_argument("--subdomains", help="subdomains per body side, H_b/H_s (default 2)")
    s.add_argument("--elements", help="Q1 elements per subdomain side, H_s/h (default 4)")
    s.add_argument("--rho", help="coefficient: a positive number, checkerboard:V (across subdomains) "
                                 "or body-checkerboard:V (across bodies)")
    s.add_argument("--f", help="right-hand side: a constant or random:SEED (default: 1 for poisson, random:0 for "
                               "multibody); contact: dostal (default) or dostal:F1,F2")
    s.add_argument("--scaling", help="rho (default) or multiplicity")
    s.add_argument("--gamma", help="exponent of the rho-scaling (default 1)")
    s.add_argument("--norm", help="hybrid: PCR stopping norm, l2 (default, the thesis's) or M (the preconditioner's)")
    s.add_argument("--projection", help="hybrid: projection onto ker(G^T), orthogonal (default, the thesis's), "
                                        "dirichlet or lumped (rho-weighted, robust for jumps)")
    s.add_argument("--rtol", help="relative residual tolerance (default 1e-6; contact 1e-5); not with direct")
    s.add_argument("--maxiter", help="iteration limit (default 1000); not with direct")
    s.add_argument("--cond", action="store_const", const=True,
                   help="compute the Lanczos condition estimate (feti, fetidp, bddc, feti-feti; hybrid reports none)")
    s.add_argument("--check", action="store_const", const=True,
                   help="also solve directly and report the error (iterative methods)")
    # a scene file's cond: true / check: true turned off from the command line (flags override the file)
    s.add_argument("--no-cond", dest="cond", action="store_const", const=False, help="no condition estimate")
    s.add_argument("--no-check", dest="check", action="store_const", const=False, help="no direct reference solve")
    s.add_argument("--preset", help="rule set: default (the project's improved rules) or thesis (the thesis's "
                                    "rules as printed: FETI/FETI-FETI orthogonal projection, active set and "
                                    "SMALBE stopping, start and removal rules; docs/methods.md)")
    # unstructured meshes and output (ddsolve.scene.unstructured, ddsolve.io.vtk)
    s.add_argument("--mesh", help="structured (default: Q1 squares sized by --subdomains/--elements) or "
                                  "unstructured (netgen P1 triangles, METIS parts)")
    s.add_argument("--geometry", help="unstructured: poisson square (default), lshape or hole; multibody square; "
                                      "contact membranes")
    s.add_argument("--maxh", help="unstructured: netgen's largest element size (default 0.1)")
    s.add_argument("--refine", help="unstructured: uniform refinements after meshing (default 0)")
    s.add_argument("--parts", help="unstructured: METIS subdomains per body (default 4)")
    s.add_argument("--mesh-file", dest="mesh_file", help="unstructured: a 2-D netgen mesh (.vol) whose "
                                                         "materials are the bodies")
    s.add_argument("--dirichlet", help="mesh file: comma-separated boundary names with u = 0 "
                                       "(default: the whole outer boundary)")
    s.add_argument("--contact-boundary", dest="contact_boundary",
                   help="mesh file, contact: name of the contact interface (default 'contact')")
    s.add_argument("--bodies-materials", dest="bodies_materials",
                   help="mesh file: comma-separated material names in body order (default: all, in mesh order)")
    s.add_argument("--primal", help="FETI-DP/BDDC primal constraints: vertices (default) or vertices+edges "
                                    "(also the edge averages)")
    s.add_argument("--output", help="write the solution, subdomain ids and contact multipliers/gap to a "
                                    ".vtu file for ParaView")
    s.add_argument("--max-memory", dest="max_memory",
                   help="memory limit for the size check, e.g. 500M or 16G (default: 90%% of the available memory)")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    return parser


def _value_options(parser: argparse.ArgumentParser) -> set[str]:
    """Option strings of ``parser`` and its subparsers that take one value."""
    out: set[str] = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                out |= _value_options(sub)
        elif action.option_strings and action.nargs is None:
            out.update(action.option_strings)
    return out


def _attach_values(argv: Sequence[str], value_options: set[str], known: set[str]) -> list[str]:
    """``--flag VALUE`` as ``--flag=VALUE`` where VALUE starts with '-' but is no option (e.g. ``-1e-6``).

    argparse takes ``-1e-6`` or ``-inf`` for an option and reports "expected one
    argument"; attached, the value reaches the field's own validation.
    """
    out: list[str] = []
    i = 0
    while i < len(argv):
        token = argv[i]
        if (token in value_options and i + 1 < len(argv) and argv[i + 1].startswith("-")
                and argv[i + 1] not in known and argv[i + 1].split("=", 1)[0] not in known and argv[i + 1] != "--"):
            out.append(f"{token}={argv[i + 1]}")
            i += 2
            continue
        out.append(token)
        i += 1
    return out


def _spec_from_args(args: argparse.Namespace) -> ProblemSpec:
    flags: dict[str, Any] = {name: getattr(args, name) for name in ProblemSpec.fields()
                             if getattr(args, name, None) is not None}
    for name in ("mesh_file", "output"):    # a flag given empty is not one left out (a review: --output ""
        if isinstance(flags.get(name), str) and not flags[name].strip():      # wrote nothing, --mesh-file ""
            raise InputError(name, "is empty: give a file name, or leave the flag out")   # solved the square)
    if args.scene is not None:
        return ProblemSpec.from_yaml(args.scene, flags)
    return ProblemSpec.from_mapping(flags)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Parse the command line (negative numeric values attached to their flags, see :func:`_attach_values`)."""
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    known: set[str] = set()

    def collect(p: argparse.ArgumentParser) -> None:
        for action in p._actions:
            known.update(action.option_strings)
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    collect(sub)
    collect(parser)
    return parser.parse_args(_attach_values(argv, _value_options(parser), known))


def _human(summary: dict[str, Any]) -> str:
    lines = [f"{summary['problem']} / {summary['method']}: bodies={summary['bodies']} "
             f"subdomains={summary['subdomains']} elements={summary['elements']} "
             f"ndof={summary['ndof']} nlambda={summary['nlambda']}",
             f"{'converged' if summary['converged'] else 'NOT converged'} in {summary['iterations']} iterations "
             f"({summary['reason']})"]
    if summary["cond"] is not None:
        lines.append(f"cond ~ {summary['cond']:.4f} (lambda_min {summary['lambda_min']:.4f}, "
                     f"lambda_max {summary['lambda_max']:.4f})")
    if summary["error_vs_direct"] is not None:
        norm = "l2" if summary.get("problem") == "contact" else "energy"       # docs/cli.md, --check
        lines.append(f"relative {norm} error vs direct: {summary['error_vs_direct']:.3e}")
    lines.append(f"setup {summary['setup_seconds']:.3f} s, solve {summary['solve_seconds']:.3f} s, "
                 f"{summary['n_factorizations']} factorizations")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status (130 after Ctrl-C: one line, no traceback; an output file being
    written is removed, the previous one kept)."""
    try:
        return _main(argv)
    except KeyboardInterrupt:
        sys.stderr.write("ddsolve: interrupted\n")
        return 130


def _main(argv: Sequence[str] | None = None) -> int:
    # under mpiexec (a launcher's environment variable; docs/parallel.md) the ranks check the input each on
    # its own, then agree (one allgather) before anything else: a rank that alone refused it (a file only it
    # cannot read, its own memory check) would otherwise leave the others waiting in MPI forever
    size = None
    if any(name in os.environ for name in ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE", "PMIX_SIZE")) \
            or os.environ.get("SLURM_STEP_NUM_TASKS", "1") not in ("", "0", "1"):     # srun -n P >= 2 without PMI
        from .parallel.run import mpi_world_size
        size = mpi_world_size() or 1
    distributed, error = False, None
    try:
        args = parse_args(argv)
        logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                            format="%(levelname)s %(name)s: %(message)s")
        max_memory = None if args.max_memory is None else parse_size(args.max_memory, "max-memory")
        spec = _spec_from_args(args)
        check_resources(spec, max_memory=max_memory)   # before NGSolve is imported or anything is built
        if size is not None:
            from .parallel.run import DISTRIBUTED, check_supported
            distributed = size > 1 or spec.method in DISTRIBUTED.get(spec.problem, ())   # -n 1: distributed too
            if distributed:
                check_supported(spec, size)
    except InputError as exc:
        error = exc
    if size is not None and size > 1:
        from .parallel.run import agree_on_input
        error, status = agree_on_input(error, None if error is not None else spec)
        if status is not None:            # no working mpi4py, or one that does not match the launcher
            return status
    try:
        if error is not None:
            raise error
        if distributed:
            from .parallel.run import main as mpi_main
            status = mpi_main(spec, args.json, _human)
            if status is not None:
                return status
        from .api import solve         # serial: no launcher, a serial method on one rank, or -n 1 without mpi4py
        result = solve(spec)
    except OutputError as exc:         # the solve finished but its file could not be written: print the result
        if exc.result is not None:
            _print_result(exc.result, args.json)
        sys.stderr.write(f"ddsolve: error: {exc}\n")
        return EXIT_INPUT
    except InputError as exc:
        sys.stderr.write(f"ddsolve: error: {exc}\n")     # one write: under mpiexec ranks' lines never interleave
        return EXIT_INPUT
    _print_result(result, args.json)
    return 0


def _print_result(result, as_json: bool) -> None:
    """The result on stdout: JSON or the summary. A reader that closed the pipe (``| head``) is not an error
    of ddsolve: stdout is pointed at /dev/null so that the interpreter's final flush stays quiet."""
    summary = result.to_dict()
    try:
        print(json.dumps(summary) if as_json else _human(summary), flush=True)
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except OSError as exc:                  # e.g. > /dev/full, a full disk: one line, not a traceback
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        sys.stderr.write(f"ddsolve: error: output: could not write the result to stdout: {exc.strerror or exc}\n")
        raise SystemExit(EXIT_INPUT) from None


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
