"""Defects a black-box review of the Python API and its output files (2026-11-28, third session) reproduced:
a user's scene with inconsistent arrays crashed the process (netgen reads the arrays unchecked), a mesh
file's result could not be written to HDF5, and solver options were refused without naming the option."""
from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from ddsolve import ProblemSpec, prepare, solve
from ddsolve.errors import InputError
from ddsolve.scene import structured_square


def _scene():
    sc = structured_square(1, 2, 2)
    sc.f = 1.0
    return sc


BAD = {
    "coords 3 columns": (lambda sc: dataclasses.replace(sc, coords=np.c_[sc.coords, np.zeros(sc.n_nodes)]),
                         "coords: must be an array of shape (n, 2)"),
    "coords nan": (lambda sc: dataclasses.replace(sc, coords=np.where(np.arange(sc.n_nodes)[:, None] == 3, np.nan,
                                                                      sc.coords)), "coords: must be finite"),
    "element id -1": (lambda sc: dataclasses.replace(sc, elements=np.where(sc.elements == 0, -1, sc.elements)),
                      "elements: id -1 is out of range"),
    "element id too large": (lambda sc: dataclasses.replace(sc, elements=sc.elements + 10 ** 6),
                             "elements: id 1000"),
    "float elements": (lambda sc: dataclasses.replace(sc, elements=sc.elements.astype(float)),
                       "elements: must hold integer ids"),
    "element_subdomain short": (lambda sc: dataclasses.replace(sc, element_subdomain=sc.element_subdomain[:-1]),
                                "element_subdomain: has 15 labels for 16 elements"),
    "element_subdomain out of range": (lambda sc: dataclasses.replace(sc, element_subdomain=sc.element_subdomain + 9),
                                       "element_subdomain: id 1"),
    "rho short": (lambda sc: dataclasses.replace(sc, rho=np.ones(3)), "rho: has 3 values for 4 subdomains"),
    "dirichlet ints": (lambda sc: dataclasses.replace(sc, dirichlet=7 * sc.dirichlet.astype(int)),
                       "dirichlet: must be a bool array of shape (25,)"),
    "dirichlet short": (lambda sc: dataclasses.replace(sc, dirichlet=sc.dirichlet[:3]), "dirichlet: must be a bool"),
    "f wrong length": (lambda sc: dataclasses.replace(sc, f=np.ones(5)), "f: must be a number, a callable"),
    "f inf": (lambda sc: dataclasses.replace(sc, f=np.inf), "f: the load must be finite"),
    "subdomain_body negative": (lambda sc: dataclasses.replace(sc, subdomain_body=sc.subdomain_body - 1),
                                "subdomain_body: needs one body label >= 0"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_an_inconsistent_user_scene_is_refused_naming_the_field(case):
    make, message = BAD[case]
    with pytest.raises(InputError) as err:
        prepare(ProblemSpec(), scene=make(_scene()))
    assert str(err.value).startswith(message), str(err.value)


def test_the_consistent_scene_solves():
    """The scene the cases above spoil: prepared and solved (the check refuses nothing valid)."""
    from ddsolve.dd import solve_fetidp

    out = solve_fetidp(prepare(ProblemSpec(), scene=_scene()).sub, rtol=1e-10)
    assert out.krylov.converged and np.all(np.isfinite(out.u))


@pytest.mark.parametrize("case", ["3d", "neg"])
def test_write_vtu_refuses_bad_arrays_instead_of_crashing(tmp_path, case):
    """Three columns of coordinates made netgen segfault (exit 139) and an element id of -1 abort with
    'double free or corruption' (exit 134); now one InputError, and no file."""
    code = f"""
import numpy as np
from ddsolve.scene import Scene
from ddsolve.io.vtk import write_vtu
coords = np.array([[0, 0], [1, 0], [1, 1], [0, 1.]])
els = np.array([[0, 1, 2, 3]])
if {case!r} == "3d": coords = np.c_[coords, np.zeros(4)]
if {case!r} == "neg": els = np.array([[0, 1, 2, -1]])
sc = Scene(coords=coords, elements=els, element_subdomain=np.array([0]), subdomain_body=np.array([0]),
           rho=np.ones(1), dirichlet=np.zeros(4, bool))
try:
    write_vtu({str(tmp_path / 'x.vtu')!r}, sc, {{"u": np.zeros(4)}}, {{}})
except Exception as e:
    print(type(e).__name__, e)
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("InputError coords:" if case == "3d" else "InputError elements: id -1")
    assert not (tmp_path / "x.vtu").exists()


def test_solution_fields_refuses_a_u_of_the_wrong_length():
    from ddsolve.io.vtk import solution_fields

    prep = prepare(ProblemSpec(subdomains=2, elements=2))
    n = prep.sub.ndof
    nodal, _ = solution_fields(prep, np.arange(n, dtype=float))
    assert nodal["u"].max() == n - 1
    for bad in (np.zeros(n + 1), np.zeros((n, 1))):
        with pytest.raises(InputError, match=rf"u: must have shape \({n},\)"):
            solution_fields(prep, bad)


def test_a_mesh_file_result_is_written_with_the_files_bodies(tmp_path):
    """write_result refused solve()'s own result of a 4-body mesh file: 'bodies: spec says 1 but the result
    says 4' (the result holds the file's bodies)."""
    from ddsolve.io.hdf5 import read_result, write_result
    from ddsolve.scene.unstructured import mesh_geometry

    vol = tmp_path / "mb.vol"
    mesh_geometry("multibody", bodies=2, maxh=0.3).Save(str(vol))
    spec = ProblemSpec(problem="multibody", method="feti-feti", mesh="unstructured", mesh_file=str(vol), parts=2)
    result = solve(spec)
    assert result.converged and result.bodies == 4 and spec.bodies == 1
    write_result(tmp_path / "r.h5", spec, result)
    assert read_result(tmp_path / "r.h5")["bodies"] == 4
    with pytest.raises(ValueError, match="method: spec says"):          # the other identity keys still checked
        write_result(tmp_path / "s.h5", dataclasses.replace(spec, method="hybrid"), result)


def test_solver_options_are_refused_naming_the_option():
    from ddsolve.contact.active_set import solve_contact_active_set
    from ddsolve.multibody.hybrid import HybridSolver
    from ddsolve.multibody.interface import GlobalInterface

    prep = prepare(ProblemSpec(problem="multibody", method="hybrid", bodies=2, subdomains=2, elements=2))
    h = HybridSolver(prep.sub, GlobalInterface(prep.sub))
    active = np.ones(h.gi.n_gl, dtype=bool)
    for kwargs, field in ((dict(norm="bad"), "norm"), (dict(projection="bad"), "projection"),
                          (dict(s_ol="bad"), "s_ol"), (dict(rtol_rule="bad"), "rtol_rule"),
                          (dict(multiplier_weight=-1.0), "multiplier_weight"),
                          (dict(multiplier_weight=float("nan")), "multiplier_weight"),
                          (dict(x0=np.zeros(3)), "x0")):
        with pytest.raises(InputError) as err:
            h.solve(active, **kwargs)
        assert err.value.field == field
    contact = prepare(ProblemSpec(problem="contact", subdomains=2, elements=2)).contact
    for value in (-1, 0, 2.5):
        with pytest.raises(InputError, match="max_outer: must be an integer >= 1"):
            solve_contact_active_set(contact, max_outer=value)


@pytest.mark.parametrize("field, value", [("contact_pairs", []), ("subdomain_body", [0, 0, 0, 0]),
                                          ("dirichlet", "list"), ("f", "list"), ("f", np.array(1.0)),
                                          ("rho", [1.0, 1.0, 1.0, 1.0])])
def test_lists_and_empty_pairs_are_taken_as_arrays(field, value):
    """Scene.check stores every field as the array the solvers read: a list of body labels, dirichlet flags or
    loads passed the first version of the check and failed later with numpy's or Python's errors, and an empty
    list of contact pairs (no pairs, one body) was refused (a review of the check)."""
    from ddsolve.dd import solve_fetidp

    sc = _scene()
    reference = solve_fetidp(prepare(ProblemSpec(), scene=_scene()).sub, rtol=1e-10).u
    value = {"list": getattr(sc, field).tolist() if field == "dirichlet" else [1.0] * sc.elements.shape[0]}.get(
        value, value) if isinstance(value, str) else value
    out = solve_fetidp(prepare(ProblemSpec(), scene=dataclasses.replace(sc, **{field: value})).sub, rtol=1e-10)
    assert out.krylov.converged and np.array_equal(out.u, reference)


@pytest.mark.parametrize("f, message", [(np.ones(16, dtype=complex), r"got complex128 of shape \(16,\)"),
                                        (True, "got True")])
def test_a_complex_or_bool_load_is_refused_naming_what_is_wrong(f, message):
    with pytest.raises(InputError, match=r"f: must be a number, a callable f\(x, y\) or a real array .*" + message):
        prepare(ProblemSpec(), scene=dataclasses.replace(_scene(), f=f))
