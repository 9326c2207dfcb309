"""Standing fuzz corpus of hostile input: every case is refused cheaply with one line.

Each case asserts exit status 2, exactly one stderr line starting
``ddsolve: error: `` (naming the expected field where there is one), no
traceback, a message of at most 200 characters, nothing on stdout, nothing
written in the working directory and a bounded time. Most cases run in-process
through :func:`ddsolve.cli.main`; the dangerous ones (``/dev/zero``, a FIFO, an
alias bomb, huge sizes) also run as subprocesses under a 500 MB address-space
limit and a timeout. Property tests (hypothesis) check that the parsers either
return a valid value or raise :class:`~ddsolve.errors.InputError` naming the
field, never another exception.
"""
from __future__ import annotations

import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ddsolve.cli import main
from ddsolve.errors import InputError
from ddsolve.limits import check_resources, estimate, parse_size
from ddsolve.spec import ProblemSpec, parse_f, parse_rho, read_scene

MAX_LINE = 350       # "ddsolve: error: " + field (32) + ": " + message (300)
MAX_SECONDS = 5.0
PREFIX = "ddsolve: error: "


def assert_refused(code: int, out: str, err: str, field: str | None) -> None:
    assert code == 2, err
    assert out == ""
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1 and err.endswith("\n"), err[:500]
    line = lines[0]
    assert line.startswith(PREFIX), line
    assert len(line) <= MAX_LINE, line
    if field is not None:
        assert line.startswith(f"{PREFIX}{field}:"), line


def refused_in_process(argv, field, capsys, tmp_path, monkeypatch):
    """Run ``main(argv)`` in an empty cwd; assert the refusal, return the line."""
    cwd = tmp_path / "cwd"
    cwd.mkdir(parents=True)
    monkeypatch.chdir(cwd)
    t0 = time.perf_counter()
    code = main(list(argv))
    seconds = time.perf_counter() - t0
    out, err = capsys.readouterr()
    assert_refused(code, out, err, field)
    assert seconds < MAX_SECONDS
    assert list(cwd.iterdir()) == []
    return err.strip()


# --------------------------------------------------------------------------- #
# Bad values for every flag
# --------------------------------------------------------------------------- #
LONG = "9" * 100_000
JUNK = ["", " ", "abc", "nan", "NaN", "inf", "-inf", "1e999", "-1e-6", "-1E-6", "0x10", "1_0", "[1]", "{}",
        "true", "\u22121", "\udcff", "\x00", "a" * 10_000, LONG, "1;rm -rf /"]

# flag -> extra problem flags that make it apply, bad values on top of JUNK, JUNK values that are valid
FLAGS: dict[str, tuple[list[str], list[str], set[str]]] = {
    "problem": ([], ["heat", "poisson2", "POISSON X"], set()),
    "method": ([], ["multigrid", "fetidp2", "feti-feti", "hybrid", "smalbe"], set()),
    "contact": (["--problem", "multibody", "--bodies", "2"], ["none", "fullx", "middle:1"], set()),
    "bodies": (["--problem", "multibody"], ["0", "-1", "2.5", "3.0000001", "2147483648"], set()),
    "subdomains": ([], ["0", "-3", "2.5", "2147483648", "1e10"], set()),
    "elements": ([], ["0", "1", "-3", "2.5", "2147483648"], set()),
    "rho": ([], ["0", "-2", "checkerboard", "checkerboard:", "checkerboard:0", "checkerboard:-1",
                 "checkerboardz:5", "checkerboard:5:5", "checkerboard:nan", "checkerboard:inf", "checker:5",
                 "body-checkerboard:", "body-checkerboardz:3", "checkerboard 5", ":5", "5:checkerboard"],
            set()),
    "f": ([], ["random:", "random:-1", "random:1.5", "random:x", "randomz", "random:2147483648", "random::1",
               "dostal", "dostal:1", "dostal:1,2,3", "dostal:a,b", "random 1"], {"-1e-6", "-1E-6"}),
    "scaling": ([], ["none", "rho2", "multiplicityx"], set()),
    "gamma": ([], ["0", "0.4", "-1", "0.49999"], set()),
    "norm": (["--problem", "multibody", "--method", "hybrid"], ["l1", "MM", "energy"], set()),
    "projection": (["--problem", "multibody", "--method", "hybrid"], ["oblique", "lumpedx"], set()),
    "rtol": ([], ["0", "1", "2", "1.0", "-0"], set()),
    "maxiter": ([], ["0", "-1", "2.5", "2147483648"], set()),
}
FLAG_CASES = [pytest.param(["solve", *extra, f"--{flag}", value], flag, id=f"{flag}={value[:12]!r}")
              for flag, (extra, bad, valid) in FLAGS.items()
              for value in dict.fromkeys(JUNK + bad) if value not in valid]
FLAG_CASES += [pytest.param(["solve", "--max-memory", v], "max-memory", id=f"max-memory={v[:12]!r}")
               for v in ["", "abc", "-1", "0", "1Q", "nan", "inf", "1e999", "-1e-6", "1.5.5G", "G", "a" * 10_000]]


@pytest.mark.parametrize("argv,field", FLAG_CASES)
def test_bad_flag_value(argv, field, capsys, tmp_path, monkeypatch):
    refused_in_process(argv, field, capsys, tmp_path, monkeypatch)


def test_negative_scientific_reaches_the_field(capsys, tmp_path, monkeypatch):
    for flag in ("rtol", "gamma", "rho", "subdomains", "elements", "maxiter"):
        line = refused_in_process(["solve", f"--{flag}", "-1e-6"], flag, capsys, tmp_path / flag, monkeypatch)
        assert "expected one argument" not in line


# --------------------------------------------------------------------------- #
# Flags that do not apply, strictness, argparse-level errors
# --------------------------------------------------------------------------- #
INAPPLICABLE = [
    (["--rho", "body-checkerboard:5"], "rho"),
    (["--contact", "middle"], "contact"),
    (["--problem", "contact", "--contact", "middle"], "contact"),
    (["--method", "direct", "--cond"], "cond"),
    (["--problem", "contact", "--cond"], "cond"),
    (["--problem", "contact", "--method", "smalbe", "--cond"], "cond"),
    (["--problem", "multibody", "--method", "direct", "--cond"], "cond"),
    (["--method", "direct", "--check"], "check"),
    (["--method", "direct", "--rtol", "1e-8"], "rtol"),
    (["--method", "direct", "--maxiter", "5"], "maxiter"),
    (["--method", "direct", "--scaling", "multiplicity"], "scaling"),
    (["--method", "direct", "--gamma", "2"], "gamma"),
    (["--scaling", "multiplicity", "--gamma", "2"], "gamma"),
    (["--norm", "M"], "norm"),
    (["--projection", "lumped"], "projection"),
    (["--problem", "multibody", "--method", "feti-feti", "--norm", "M"], "norm"),
    (["--problem", "contact", "--projection", "dirichlet"], "projection"),
    (["--f", "dostal"], "f"),
    (["--problem", "multibody", "--f", "dostal:-1,-2"], "f"),
    (["--bodies", "2"], "bodies"),
    (["--problem", "contact", "--bodies", "3"], "bodies"),
    (["--problem", "multibody", "--method", "fetidp"], "method"),
    (["--problem", "contact", "--method", "hybrid"], "method"),
]
ARGPARSE = [
    ([], "arguments"), (["solve", "--foo"], "arguments"), (["solve", "--rtol"], "arguments"),
    (["solve", "a.yaml", "b.yaml"], "arguments"), (["solve", "--rtol", "--json"], "arguments"), (["frobnicate"], "arguments"), (["solve", "--cond=1"], "arguments"),
    (["solve", "--" + "x" * 10_000], "arguments"), (["solve", "-" * 5000], "arguments"),
    (["solve", ""], "scene"), (["solve", "   "], "scene"), (["solve", "/nonexistent/scene.yaml"], "scene"),
    (["solve", "a\x00b"], "scene"), (["solve", "x" * 5000], "scene"), (["solve", "\udcff.yaml"], "scene"),
]
HUGE = [
    (["--subdomains", "1000", "--elements", "1000"], "elements"),
    (["--problem", "multibody", "--bodies", "100000"], "bodies"),
    (["--subdomains", "100000", "--elements", "2"], "subdomains"),
    (["--elements", "100000"], "elements"),
    (["--problem", "contact", "--subdomains", "3000", "--elements", "50"], "subdomains"),
    (["--subdomains", "2147483647", "--elements", "2147483647"], "elements"),
    (["--problem", "multibody", "--bodies", "2147483647", "--subdomains", "2"], "bodies"),
    (["--subdomains", "4", "--elements", "64", "--max-memory", "10M"], "elements"),
    (["--method", "direct", "--subdomains", "65", "--elements", "64", "--max-memory", "1G"], "subdomains"),
    (["--subdomains", "20000", "--elements", "2", "--max-memory", "1P"], "subdomains"),   # set-up time
]


@pytest.mark.parametrize("argv,field", [pytest.param(a, f, id=" ".join(a)[:40]) for a, f in INAPPLICABLE + HUGE])
def test_inapplicable_and_huge(argv, field, capsys, tmp_path, monkeypatch):
    refused_in_process(["solve", *argv], field, capsys, tmp_path, monkeypatch)


@pytest.mark.parametrize("argv,field", [pytest.param(a, f, id=repr(a)[:40]) for a, f in ARGPARSE])
def test_argument_errors(argv, field, capsys, tmp_path, monkeypatch):
    refused_in_process(argv, field, capsys, tmp_path, monkeypatch)


def test_default_values_never_inapplicable():
    """A field at its default is accepted for every problem and method (the studies always set them)."""
    from ddsolve.options import METHODS
    for problem, methods in METHODS.items():
        for method in methods:
            spec = ProblemSpec.from_mapping({"problem": problem, "method": method, "contact": "full", "cond": False,
                                             "check": False, "scaling": "rho", "gamma": 1, "norm": "l2",
                                             "projection": "orthogonal", "maxiter": 1000, "rtol": None, "rho": 1})
            assert spec.method == method
    # the configured studies: cond with the hybrid method (table_4), check with every iterative method
    ProblemSpec(problem="multibody", method="hybrid", bodies=2, cond=True, check=True)
    ProblemSpec(problem="contact", method="direct", rtol=1e-5)


# --------------------------------------------------------------------------- #
# Hostile scene files
# --------------------------------------------------------------------------- #
def _bomb(levels: int = 9) -> str:
    lines = ['l0: &l0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for i in range(1, levels):
        lines.append(f"l{i}: &l{i} [" + ",".join([f"*l{i - 1}"] * 9) + "]")
    lines.append(f"problem: *l{levels - 1}")
    return "\n".join(lines) + "\n"


SCENES: dict[str, tuple[object, str | None]] = {
    "alias_bomb": (_bomb(), "scene"),
    "alias_bomb_in_value": (("a: &a [x, x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
                             "c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b, *b]\nproblem: [*c, *c, *c, *c, *c, *c, *c, "
                             "*c, *c, *c, *c]\n"), "scene"),
    "recursive_alias": ("problem: &a [*a]\n", None),
    "deep_flow": ("problem: " + "[" * 50_000 + "]" * 50_000 + "\n", "scene"),
    "deep_mapping": ("problem: " + "{a: " * 50_000 + "1" + "}" * 50_000 + "\n", "scene"),
    "deep_block": ("".join("  " * i + f"k{i}:\n" for i in range(200)) + "  " * 200 + "x: 1\n", "scene"),
    "non_utf8": (b"problem: poisson\nmethod: \xff\xfe\xfd\n", "scene"),
    "latin1": ("problem: caf\xe9\n".encode("latin-1"), "scene"),
    "utf16": ("problem: poisson\n".encode("utf-16"), "scene"),
    "nul_byte": (b"problem: pois\x00son\n", "scene"),
    "big_value_10MB": ("problem: " + "x" * 10_000_000 + "\n", "scene"),
    "big_file_2MB": ("# " + "y" * 2_000_000 + "\nproblem: poisson\n", "scene"),
    "value_900kB": ("problem: " + "x" * 900_000 + "\n", "problem"),
    "key_900kB": ("k" * 900_000 + ": 1\n", None),
    "many_keys": ("".join(f"k{i}: {i}\n" for i in range(20_000)), "scene"),
    "long_list": ("problem: [" + "1, " * 200_000 + "1]\n", "scene"),
    "list": ("- problem: poisson\n- method: feti\n", "scene"),
    "scalar": ("poisson\n", "scene"),
    "number": ("42\n", "scene"),
    "unknown_key": ("subdomain: 3\n", "subdomain"),
    "int_key": ("1: 2\n", "1"),
    "null_key": ("~: 2\n", None),
    "unhashable_key": ("? [a, b]\n: 1\n", "scene"),
    "malformed": ("method: [fetidp\nsubdomains: 3\n", "scene"),
    "tab_indent": ("problem:\n\t- poisson\n", "scene"),
    "two_documents": ("problem: poisson\n---\nmethod: feti\n", "scene"),
    "python_tag": ("problem: !!python/object/apply:os.system ['touch pwned']\n", "scene"),
    "custom_tag": ("problem: !foo bar\n", "scene"),
    "bad_timestamp": ("problem: 2020-13-45\n", "scene"),
    "timestamp": ("problem: 2020-01-01\n", "problem"),
    "binary": ("problem: !!binary aGVsbG8=\n", "problem"),
    "subdomains_list": ("subdomains: [1, 2]\n", "subdomains"),
    "subdomains_map": ("subdomains: {a: 1}\n", "subdomains"),
    "subdomains_bool": ("subdomains: yes\n", "subdomains"),
    "subdomains_nan": ("subdomains: .nan\n", "subdomains"),
    "elements_inf": ("elements: .inf\n", "elements"),
    "maxiter_minf": ("maxiter: -.inf\n", "maxiter"),
    "gamma_nan": ("gamma: .nan\n", "gamma"),
    "rtol_inf": ("rtol: .inf\n", "rtol"),
    "rtol_nan": ("rtol: .NaN\n", "rtol"),
    "rho_nan": ("rho: .nan\n", "rho"),
    "rho_inf": ("rho: .inf\n", "rho"),
    "f_inf": ("f: -.inf\n", "f"),
    "f_list": ("f: [1, 2]\n", "f"),
    "cond_string": ("cond: 'yes'\n", "cond"),
    "cond_int": ("cond: 1\n", "cond"),
    "check_list": ("check: [true]\n", "check"),
    "problem_int": ("problem: 5\n", "problem"),
    "method_list": ("method: [fetidp]\n", "method"),
    "scaling_bool": ("scaling: no\n", "scaling"),
    "huge_int": ("subdomains: " + "9" * 4000 + "\n", "subdomains"),
    "huge_int_5000_digits": ("subdomains: " + "9" * 5000 + "\n", "scene"),   # beyond Python's int() digit limit
    "huge_sizes": ("subdomains: 1000\nelements: 1000\n", "elements"),
    "inapplicable": ("problem: poisson\ncontact: middle\n", "contact"),
    "rho_pattern": ("rho: checkerboardz:5\n", "rho"),
}


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("scenes")
    for name, (content, _) in SCENES.items():
        data = content.encode("utf-8") if isinstance(content, str) else content
        (root / f"{name}.yaml").write_bytes(data)
    os.mkfifo(root / "fifo.yaml")
    (root / "directory.yaml").mkdir()
    os.symlink("/dev/zero", root / "zero_link.yaml")
    return root


@pytest.mark.parametrize("name", list(SCENES))
def test_hostile_scene(name, scene_dir, capsys, tmp_path, monkeypatch):
    line = refused_in_process(["solve", str(scene_dir / f"{name}.yaml")], SCENES[name][1], capsys, tmp_path,
                              monkeypatch)
    assert "lol" * 5 not in line and "x" * 100 not in line


@pytest.mark.parametrize("path", ["/dev/zero", "/dev/null", "/proc/self/mem", "/", "fifo.yaml",
                                  "directory.yaml", "zero_link.yaml", "missing.yaml"])
def test_special_files(path, scene_dir, capsys, tmp_path, monkeypatch):
    target = path if path.startswith("/") else str(scene_dir / path)
    refused_in_process(["solve", target], "scene", capsys, tmp_path, monkeypatch)


def test_scene_flag_overrides_are_still_validated(scene_dir, capsys, tmp_path, monkeypatch):
    (tmp_path / "ok.yaml").write_text("problem: poisson\nsubdomains: 2\n")
    refused_in_process(["solve", str(tmp_path / "ok.yaml"), "--subdomains", "-1e-6"], "subdomains", capsys,
                       tmp_path, monkeypatch)


def test_read_scene_limits(tmp_path):
    ok = tmp_path / "ok.yaml"
    ok.write_text("a: &x [1, 2]\nb: *x\n")
    assert read_scene(ok) == {"a": [1, 2], "b": [1, 2]}
    (tmp_path / "empty.yaml").write_text("")
    assert read_scene(tmp_path / "empty.yaml") == {}
    nested = tmp_path / "nested.yaml"
    nested.write_text("a: " + "[" * 20 + "]" * 20 + "\n")   # within the depth bound
    assert read_scene(nested)["a"] == [[[[[[[[[[[[[[[[[[[[]]]]]]]]]]]]]]]]]]]]


# --------------------------------------------------------------------------- #
# Dangerous cases as subprocesses: 500 MB address space, CPU time, wall timeout
# --------------------------------------------------------------------------- #
def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (500 << 20, 500 << 20))


DANGEROUS = [
    (["/dev/zero"], "scene"),
    (["fifo.yaml"], "scene"),
    (["alias_bomb.yaml"], "scene"),
    (["big_value_10MB.yaml"], "scene"),
    (["--subdomains", "1000", "--elements", "1000"], "elements"),
    (["--problem", "multibody", "--bodies", "100000"], "bodies"),
    (["--rtol", "-1e-6"], "rtol"),
]


@pytest.mark.parametrize("argv,field", [pytest.param(a, f, id=" ".join(a)[:40]) for a, f in DANGEROUS])
def test_dangerous_subprocess(argv, field, scene_dir, tmp_path):
    argv = [str(scene_dir / a) if a.endswith(".yaml") else a for a in argv]
    env = {**os.environ, "PYTHONWARNINGS": "ignore", "OMP_NUM_THREADS": "1"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run([sys.executable, "-m", "ddsolve", "solve", *argv], capture_output=True, text=True,
                          check=False, env=env, timeout=60, cwd=tmp_path, preexec_fn=_limit_memory, stdin=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    assert_refused(proc.returncode, proc.stdout, proc.stderr, field)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    assert cpu < MAX_SECONDS
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- #
# Python API: ProblemSpec validates itself; numpy scalars accepted
# --------------------------------------------------------------------------- #
API_BAD = [
    ({"gamma": -1}, "gamma"), ({"gamma": 0.3}, "gamma"), ({"gamma": float("nan")}, "gamma"),
    ({"scaling": "none"}, "scaling"), ({"bodies": 2}, "bodies"), ({"method": "multigrid"}, "method"),
    ({"method": 5}, "method"), ({"problem": None}, "problem"), ({"problem": ["poisson"]}, "problem"),
    ({"subdomains": "abc"}, "subdomains"), ({"subdomains": None}, "subdomains"), ({"subdomains": 2.5}, "subdomains"),
    ({"subdomains": True}, "subdomains"), ({"subdomains": [2]}, "subdomains"), ({"subdomains": 10**400}, "subdomains"),
    ({"elements": np.int64(1)}, "elements"), ({"elements": np.float64("nan")}, "elements"),
    ({"rho": None}, "rho"), ({"rho": [1.0]}, "rho"), ({"rho": {"a": 1}}, "rho"), ({"rho": -1}, "rho"),
    ({"rho": b"checkerboard:5"}, "rho"), ({"f": object()}, "f"), ({"f": float("inf")}, "f"),
    ({"rtol": 0}, "rtol"), ({"rtol": "x"}, "rtol"), ({"rtol": 1.5}, "rtol"), ({"maxiter": 0}, "maxiter"),
    ({"maxiter": np.int32(-5)}, "maxiter"), ({"cond": 1}, "cond"), ({"cond": "true"}, "cond"),
    ({"check": None}, "check"), ({"contact": "middle"}, "contact"), ({"norm": "M"}, "norm"),
    ({"projection": None}, "projection"), ({"norm": 3}, "norm"),
    ({"problem": "multibody", "method": "hybrid", "norm": "energy"}, "norm"),
    ({"problem": "multibody", "bodies": np.float64(2.5)}, "bodies"),
]


@pytest.mark.parametrize("kwargs,field", [pytest.param(k, f, id=f"{f}-{i}") for i, (k, f) in enumerate(API_BAD)])
def test_api_constructor_refuses(kwargs, field):
    with pytest.raises(InputError) as info:
        ProblemSpec(**kwargs)
    assert info.value.field == field
    assert len(str(info.value)) <= MAX_LINE - len(PREFIX)


def test_from_mapping_shares_validation():
    for kwargs, field in API_BAD:
        mapping = {k: v for k, v in kwargs.items() if v is not None}   # None means "default" in a mapping
        if mapping != kwargs:
            continue
        with pytest.raises(InputError) as info:
            ProblemSpec.from_mapping(mapping)
        assert info.value.field == field
    for bad in ([("problem", "poisson")], "poisson", None, 5):
        with pytest.raises(InputError):
            ProblemSpec.from_mapping(bad)
    with pytest.raises(InputError, match="unknown field"):
        ProblemSpec.from_mapping({"subdomain": 3})
    with pytest.raises(InputError, match="unknown field"):
        ProblemSpec.from_mapping({("a",): 3})


def test_numpy_scalars_accepted():
    spec = ProblemSpec(problem=np.str_("multibody"), method="hybrid", bodies=np.int64(3), subdomains=np.int32(2),
                       elements=np.uint8(4), rho=np.float32(2.0), f=np.float64(-1.5), gamma=np.float64(1.0),
                       rtol=np.float64(1e-7), maxiter=np.int64(50), cond=np.bool_(True), check=np.bool_(False))
    assert (spec.bodies, spec.subdomains, spec.elements, spec.maxiter) == (3, 2, 4, 50)
    assert all(type(v) is int for v in (spec.bodies, spec.subdomains, spec.elements, spec.maxiter))
    assert spec.cond is True and type(spec.check) is bool and spec.f == -1.5 and spec.rtol == 1e-7
    assert ProblemSpec.from_mapping(spec.to_dict()) == spec


def test_valid_input_unchanged():
    spec = ProblemSpec()
    assert spec.to_dict() == {"problem": "poisson", "method": "fetidp", "bodies": 1, "subdomains": 2, "elements": 4,
                              "rho": 1.0, "f": 1.0, "contact": "full", "scaling": "rho", "gamma": 1.0, "norm": "l2",
                              "projection": "orthogonal", "rtol": 1e-6, "maxiter": 1000, "cond": False,
                              "check": False, "preset": "default", "mesh": "structured", "geometry": "square", "maxh": 0.1,
                              "refine": 0, "parts": 4, "mesh_file": "", "dirichlet": "boundary",
                              "contact_boundary": "contact", "bodies_materials": "", "primal": "vertices",
                              "output": ""}
    contact = ProblemSpec.from_mapping({"problem": "Contact", "method": "SMALBE", "subdomains": "3"})
    assert (contact.problem, contact.method, contact.bodies, contact.subdomains, contact.f, contact.rtol) == \
        ("contact", "smalbe", 2, 3, "dostal", 1e-5)
    assert ProblemSpec(rho="Checkerboard:10").rho == "Checkerboard:10"
    assert parse_rho(" checkerboard : 1e4 ") == ("checkerboard", 1e4)
    assert parse_f("random") == ("random", 0) and parse_f("dostal:-3, -1") == ("dostal", (-3.0, -1.0))
    from dataclasses import replace
    assert replace(spec, elements=8).elements == 8
    with pytest.raises(InputError, match="elements"):
        replace(spec, elements=0)


# --------------------------------------------------------------------------- #
# Resource estimates
# --------------------------------------------------------------------------- #
def test_estimate_model():
    small = estimate(ProblemSpec(subdomains=2, elements=4))
    assert small.n_subdomains == 4 and small.n_w == 4 * 25 and small.ndof == 81
    big = estimate(ProblemSpec(subdomains=16, elements=32))
    assert 300e6 < big.memory_bytes < 800e6            # measured peak RSS 412 MB
    direct = estimate(ProblemSpec(subdomains=16, elements=32, method="direct"))
    assert direct.memory_bytes > big.memory_bytes - 200e6
    contact = estimate(ProblemSpec(problem="contact", subdomains=3, elements=4))
    assert contact.n_subdomains == 18 and contact.ndof == 2 * 13 ** 2
    assert check_resources(ProblemSpec(subdomains=2, elements=4)).n_w == 100
    with pytest.raises(InputError, match="too large"):
        check_resources(ProblemSpec(subdomains=2, elements=4), max_memory="1M")
    assert check_resources(ProblemSpec(subdomains=64, elements=64), max_memory="1P").n_w == 64 ** 2 * 65 ** 2


@pytest.mark.parametrize("text,expected", [("500M", 500 * 2**20), ("8G", 8 * 2**30), ("1.5GiB", 1.5 * 2**30),
                                           ("2e9", 2e9), ("1024", 1024.0), ("16 kB", 16 * 1024.0), (2**20, 2**20)])
def test_parse_size(text, expected):
    assert parse_size(text) == expected


# --------------------------------------------------------------------------- #
# Property tests: a parser returns a valid value or raises InputError naming the field
# --------------------------------------------------------------------------- #
ANY_VALUE = st.one_of(st.text(max_size=40), st.floats(allow_nan=True, allow_infinity=True),
                      st.integers(min_value=-10**30, max_value=10**30), st.booleans(), st.none(),
                      st.lists(st.integers(), max_size=3), st.binary(max_size=8),
                      st.from_regex(r"\s*(body-)?checkerboard\s*:?\s*[-+]?[0-9.eE]*\s*", fullmatch=True),
                      st.from_regex(r"\s*(random|dostal)\s*:?[-+0-9., eE]*", fullmatch=True))
PROPERTY = settings(max_examples=150, derandomize=True, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])


@PROPERTY
@given(ANY_VALUE)
def test_parse_rho_property(value):
    try:
        kind, out = parse_rho(value)
    except InputError as exc:
        assert exc.field == "rho" and len(str(exc)) < MAX_LINE
        return
    assert kind in ("constant", "checkerboard", "body-checkerboard") and math.isfinite(out) and out > 0


@PROPERTY
@given(ANY_VALUE)
def test_parse_f_property(value):
    try:
        kind, out = parse_f(value)
    except InputError as exc:
        assert exc.field == "f" and len(str(exc)) < MAX_LINE
        return
    if kind == "random":
        assert isinstance(out, int) and 0 <= out < 2**31
    elif kind == "dostal":
        assert len(out) == 2 and all(math.isfinite(v) for v in out)
    else:
        assert kind == "constant" and math.isfinite(out)


@PROPERTY
@given(st.sampled_from(["bodies", "subdomains", "elements", "maxiter"]), ANY_VALUE)
def test_integer_fields_property(field, value):
    extra = {"problem": "multibody"} if field == "bodies" else {}
    try:
        spec = ProblemSpec(**extra, **{field: value})
    except InputError as exc:
        assert exc.field == field and len(str(exc)) < MAX_LINE
        return
    out = getattr(spec, field)
    assert type(out) is int and 1 <= out < 2**31


@PROPERTY
@given(st.sampled_from(["gamma", "rtol"]), ANY_VALUE)
def test_float_fields_property(field, value):
    try:
        spec = ProblemSpec(**{field: value})
    except InputError as exc:
        assert exc.field == field and len(str(exc)) < MAX_LINE
        return
    out = getattr(spec, field)
    assert isinstance(out, float) and math.isfinite(out)
    assert (out >= 0.5) if field == "gamma" else (0 < out < 1)


@PROPERTY
@given(st.dictionaries(st.sampled_from(ProblemSpec.fields()), ANY_VALUE, max_size=5))
def test_from_mapping_property(mapping):
    try:
        ProblemSpec.from_mapping(mapping)
    except InputError as exc:
        assert exc.field in mapping and len(str(exc)) < MAX_LINE
