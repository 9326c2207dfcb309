"""DDInverse on a 3D tetrahedral mesh: a box with a spherical hole, a Robin condition on the hole; writes VTK."""
import sys

import ngsolve as ngs
from netgen.csg import CSGeometry, OrthoBrick, Pnt, Sphere

from ddsolve.ngsolve import DDInverse

geo = CSGeometry()
geo.Add(OrthoBrick(Pnt(0, 0, 0), Pnt(2, 1, 1)).bc("outer") - Sphere(Pnt(1, 0.5, 0.5), 0.3).bc("hole"))
mesh = ngs.Mesh(geo.GenerateMesh(maxh=0.1))
fes = ngs.H1(mesh, order=2, dirichlet="outer")
u, v = fes.TnT()
a = ngs.BilinearForm((1 + ngs.x) * ngs.grad(u) * ngs.grad(v) * ngs.dx + 10 * u * v * ngs.ds("hole"))
f = ngs.LinearForm(10 * v * ngs.ds("hole")).Assemble()        # heat flux into the hole's surface
inv = DDInverse(a, method="fetidp", parts=24, rtol=1e-10)
gfu = ngs.GridFunction(fes)
gfu.vec.data = inv * f.vec
print(f"{inv.iterations} iterations on {inv.n_parts} parts, {fes.ndof} dofs")
ngs.VTKOutput(mesh, coefs=[gfu], names=["u"], filename=sys.argv[1] if len(sys.argv) > 1 else "ddinverse_3d").Do()
