"""Two membranes in contact, meshed by netgen as one geometry, solved by ddsolve; writes VTK."""
import sys

import ngsolve as ngs
from netgen.occ import Glue, MoveTo, OCCGeometry

from ddsolve.ngsolve import contact_solve

left, right = MoveTo(0, 0).Rectangle(1, 1).Face(), MoveTo(1, 0).Rectangle(1, 1).Face()
left.faces.name, right.faces.name = "left", "right"
shape = Glue([left, right])
for edge in shape.edges:    # x = 0 clamped, x = 1 the contact line
    edge.name = {0.0: "wall", 1.0: "gap"}.get(round(edge.center.x, 9), "free")
mesh = ngs.Mesh(OCCGeometry(shape, dim=2).GenerateMesh(maxh=0.05))
f = ngs.IfPos(ngs.x - 1, ngs.IfPos(0.25 - ngs.y, -1, 0), ngs.IfPos(ngs.y - 0.75, -3, 0))  # Dostal's loads
res = contact_solve(mesh, ("left", "right"), contact="gap", dirichlet="wall", f=f, method="active-set", parts=4)
print(f"{res.reason}; {res.active.sum()} of {res.active.size} contact nodes active, KKT {res.kkt_residual:.1e}")
ngs.VTKOutput(mesh, coefs=list(res.gfu), names=["u1", "u2"], filename=sys.argv[1] if len(sys.argv) > 1 else "contact").Do()
