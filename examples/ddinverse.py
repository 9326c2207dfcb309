"""Solve a user's NGSolve problem with ddsolve's BDDC (DDInverse) and write VTK."""
import sys

import ngsolve as ngs
from netgen.geom2d import unit_square

from ddsolve.ngsolve import DDInverse

mesh = ngs.Mesh(unit_square.GenerateMesh(maxh=0.05))
fes = ngs.H1(mesh, order=3, dirichlet="left|bottom")
u, v = fes.TnT()
a = ngs.BilinearForm(ngs.IfPos(ngs.x - 0.5, 100, 1) * ngs.grad(u) * ngs.grad(v) * ngs.dx)  # not assembled
f = ngs.LinearForm(ngs.sin(3 * ngs.y) * v * ngs.dx).Assemble()
inv = DDInverse(a, method="bddc", parts=16, rtol=1e-10)
gfu = ngs.GridFunction(fes)
gfu.vec.data = inv * f.vec
print(f"{inv.iterations} iterations on {inv.n_parts} parts, {fes.ndof} dofs")
ngs.VTKOutput(mesh, coefs=[gfu], names=["u"], filename=sys.argv[1] if len(sys.argv) > 1 else "ddinverse").Do()
