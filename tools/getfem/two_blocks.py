#!/usr/bin/env python3
"""Two deformable blocks in frictional contact, solved by GetFEM: a peer for glissade (issue 44, item 3).

The case (plane strain, SI in this docstring): a steel block (E 200 GPa, nu 0.3, rho 7800
kg/m^3), 40 x 10 mm, its bottom face clamped, meshed with 16 x 4 bilinear quads; on it, centred,
an aluminium block (E 70 GPa, nu 0.33, rho 2700 kg/m^3), 20 x 10 mm, 8 x 4 quads, whose bottom
nodes sit on the steel block's top nodes (matching nodes, 2.5 mm apart). The aluminium block is
pressed on its top face by 5 MPa from t = 0 (a static solve first) and pushed on its left face
by a traction that rises from 0 to 4 MPa over 400 us. Coulomb friction f = 0.3 between the
blocks: the push (up to 40 kN/m) passes the friction limit (0.3 x 5 MPa x 20 mm = 30 kN/m) at
t = 300 us, and the upper block slides for the last 100 us. Newmark over 400 us, consistent mass.

QoIs, at every step (their histories give each QoI's scale):
- slip: the x displacement of the upper block's bottom centre node (x = 20 mm) less that of the
  lower block's node under it, less its static value (glissade's `slip`, side 2 minus side 1);
- force_x, force_y: the resultant of the contact stress on the lower block (N/m; glissade's
  `force` on side 1, the lower block);
- corner_ux: the x displacement of the upper block's top left corner (10 mm, 20 mm), total.
The rigid-block estimate of the final slip, with the lower block rigid, is
x = a (T - t*)^3 / (6 m) = 3.09e-5 m (a = 4 MPa x 10 mm / 400 us, t* = 300 us, m = 0.54 kg/m).

The contact: node to node, as in glissade. Both blocks are in one mesh and one displacement
field u; the upper block's mesh is raised by 0.1 nm before the merge so that its bottom nodes
stay apart from the lower block's top nodes (the contact's gap is 0, so the 0.1 nm does not
enter it). GetFEM's basic contact brick (`add_basic_contact_brick`, nodal Alart-Curnier,
non-symmetric) pairs each bottom node of the upper block with the lower block's node at the same
place, through matrices BN and BT built here. The pairing is fixed (small sliding: the slip is
at most 31 um, 1.2 % of an element). The friction acts on the slip since the previous step: the
brick's tangential term is lambda_t - r BT u - r gamma_c BT wt, so gamma_c = -1 and wt = the
previous step's displacement. The other choices are those of sliding_block.py, for the same
reasons: um-N-s units (E / 1e12, rho / 1e24), an absolute Newton residual of 1e-10, line search
"basic", and the static solve started with each node's normal force at its share of the
pressure.

GetFEM's two-mesh bricks did not serve (README.md): the integral one
(`add_integral_contact_between_nonmatching_meshes_brick`) stops with "non invertible matrix" at
its first assembly, and the nodal one takes no reference displacement for the friction.

GetFEM is optional: Debian's python3-getfem (tools/getfem/install.sh), imported by the system
Python, /usr/bin/python3. Without it the script says so and exits 3.

  /usr/bin/python3 tools/getfem/two_blocks.py [--steps N] [--beta B --gamma G] [--friction F] [--json OUT]
  /usr/bin/python3 tools/getfem/two_blocks.py table [--json OUT]
"""

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from sliding_block import have_getfem  # noqa: E402  (one check for both models)

# The case, SI. Lower block [0, 40] x [0, 10] mm, upper block [10, 30] x [10, 20] mm.
STEEL = dict(E=200e9, nu=0.3, rho=7800.0)
ALU = dict(E=70e9, nu=0.33, rho=2700.0)
LOWER = dict(origin=(0.0, 0.0), size=(0.04, 0.01), elements=(16, 4))
UPPER = dict(origin=(0.01, 0.01), size=(0.02, 0.01), elements=(8, 4))
PRESSURE, PUSH, DURATION, FRICTION = 5e6, 4e6, 4e-4, 0.3
SLIP_POINT = (0.02, 0.01)    # the upper block's bottom centre, on the interface
CORNER = (0.01, 0.02)        # the upper block's top left corner
SEPARATION = 1e-4  # um: the upper block's mesh is raised by this (the contact's gap stays 0)
UM = 1e6  # metres to micrometres; stresses N/um^2 = Pa / 1e12, densities / 1e24
TRAPEZOIDAL, DISSIPATIVE = (0.25, 0.5), (0.3025, 0.6)
TABLE_STEPS = (200, 400, 800)  # dt 2, 1, 0.5 us
QOIS = ("slip", "force_x", "force_y", "corner_ux")
# regions
L_BOTTOM, L_TOP, U_BOTTOM, U_TOP, U_LEFT, LOWER_BODY, UPPER_BODY = 1, 2, 3, 4, 5, 6, 7


def rigid_estimate(f=FRICTION):
    """The final slip if the lower block were rigid and the upper one a rigid mass:
    x = a (T - t*)^3 / (6 m), a the push's rate (N/m per s), t* when the push reaches f times
    the normal force, m the upper block's mass per metre."""
    w, h = UPPER["size"]
    mass = ALU["rho"] * w * h
    rate = PUSH * h / DURATION
    onset = f * PRESSURE * w / rate
    return rate * max(DURATION - onset, 0.0) ** 3 / (6.0 * mass)


def _box(gf, np, box):
    """A structured mesh of the box (um), Q1 quads."""
    (x0, y0), (w, h), (nx, ny) = box["origin"], box["size"], box["elements"]
    return gf.Mesh("cartesian", np.linspace(x0 * UM, (x0 + w) * UM, nx + 1),
                   np.linspace(y0 * UM, (y0 + h) * UM, ny + 1))


def _at(nodes, dofs, p):
    """The x dof, among `dofs`, of the node at p (m), within 1 nm."""
    hits = [d for d in dofs if d % 2 == 0 and abs(nodes[0, d] - p[0] * UM) < 1e-3 and abs(nodes[1, d] - p[1] * UM) < 1e-3]
    if len(hits) != 1:
        raise ValueError(f"{len(hits)} nodes at {p}")
    return hits[0]


def solve(steps, beta=0.25, gamma=0.5, f=FRICTION, r_factor=1.0, residual=1e-10, max_iter=100):
    """Static solve under the pressure, then `steps` Newmark steps; returns a dict with the QoIs'
    histories and final values (SI), the CPU time and the Newton iterations."""
    import getfem as gf
    import numpy as np

    gf.util_trace_level(0)
    cpu = time.process_time()
    # One mesh holding both blocks, with the interface nodes twice, so that one displacement
    # field u carries both bodies and the basic contact brick can pair them node to node. The
    # upper block is raised by SEPARATION (0.1 nm) so that the merge keeps its bottom nodes apart
    # from the lower block's top nodes (a negative tolerance keeps every point apart, and the
    # elements of each block then share no node either).
    m = _box(gf, np, LOWER)
    n_lower = m.nbcvs()
    upper_mesh = _box(gf, np, UPPER)
    upper_mesh.translate([0.0, SEPARATION])
    m.merge(upper_mesh, 0.0)
    assert m.nbpts() == sum((b["elements"][0] + 1) * (b["elements"][1] + 1) for b in (LOWER, UPPER))
    cvs = np.arange(m.nbcvs())
    m.set_region(LOWER_BODY, np.array([cvs[cvs < n_lower]]))
    m.set_region(UPPER_BODY, np.array([cvs[cvs >= n_lower]]))
    faces = m.outer_faces()
    normals = m.normal_of_faces(faces)
    upper = faces[0] >= n_lower
    m.set_region(L_BOTTOM, faces[:, ~upper & (normals[1] < -0.5)])
    m.set_region(L_TOP, faces[:, ~upper & (normals[1] > 0.5)])
    m.set_region(U_BOTTOM, faces[:, upper & (normals[1] < -0.5)])
    m.set_region(U_TOP, faces[:, upper & (normals[1] > 0.5)])
    m.set_region(U_LEFT, faces[:, upper & (normals[0] < -0.5)])

    mfu = gf.MeshFem(m, 2)
    mfu.set_fem(gf.Fem("FEM_QK(2,1)"))
    mim = gf.MeshIm(m, gf.Integ("IM_GAUSS_PARALLELEPIPED(2,3)"))
    md = gf.Model("real")
    md.add_fem_variable("u", mfu)
    for name, mat, region in (("u", ALU, UPPER_BODY), ("l", STEEL, LOWER_BODY)):
        e, nu = mat["E"] / 1e12, mat["nu"]
        md.add_initialized_data(f"lambda_{name}", [e * nu / ((1 + nu) * (1 - 2 * nu))])  # plane strain
        md.add_initialized_data(f"mu_{name}", [e / (2 * (1 + nu))])
        md.add_isotropic_linearized_elasticity_brick(mim, "u", f"lambda_{name}", f"mu_{name}", region)
    md.add_initialized_data("top", [0.0, -PRESSURE / 1e12])
    md.add_source_term_brick(mim, "u", "top", U_TOP)
    md.add_initialized_data("push", [0.0, 0.0])
    md.add_source_term_brick(mim, "u", "push", U_LEFT)
    md.add_Dirichlet_condition_with_simplification("u", L_BOTTOM)

    # Node-to-node contact: each node of the upper block's bottom face with the lower block's
    # node at the same place. BN u = u_lower_y - u_upper_y <= 0 (no interpenetration), BT u =
    # u_upper_x - u_lower_x (the slip). The multipliers are nodal forces: lambda_n <= 0 in
    # contact, the upper node gets -lambda_n up and lambda_t along x, the lower node the opposite.
    nodes = mfu.basic_dof_nodes()
    slaves = [d for d in mfu.basic_dof_on_region(U_BOTTOM) if d % 2 == 0]
    lower_top = mfu.basic_dof_on_region(L_TOP)
    pairs = [(d, _at(nodes, lower_top, nodes[:, d] / UM)) for d in slaves]
    nc, ndof = len(pairs), mfu.nbdof()
    BN = gf.Spmat("empty", nc, ndof)
    BT = gf.Spmat("empty", nc, ndof)
    for i, (du, dl) in enumerate(pairs):
        BN[i, du + 1], BN[i, dl + 1] = -1.0, 1.0
        BT[i, du], BT[i, dl] = 1.0, -1.0
    md.add_variable("lambda_n", nc)
    md.add_variable("lambda_t", nc)
    md.add_initialized_data("r", [r_factor * ALU["E"] / 1e12])  # nodal force per displacement
    md.add_initialized_data("f", [f])
    md.add_initialized_data("gap", [0.0])
    md.add_initialized_data("alpha", np.ones(nc))
    # The friction acts on BT (u - wt): the brick's tangential term is lambda_t - r BT u
    # - r gamma_c BT wt, so gamma_c = -1 and wt = the previous step's displacement.
    md.add_initialized_data("gamma_c", [-1.0])
    md.add_initialized_data("wt", np.zeros(ndof))
    md.add_basic_contact_brick("u", "lambda_n", "lambda_t", "r", BN, BT, "f", "gap", "alpha", 1, "gamma_c", "wt")

    def newton():
        it, converged = md.solve("max_res", residual, "max_iter", max_iter, "lsearch", "basic")
        if not converged:
            raise RuntimeError(f"Newton did not converge in {max_iter} iterations")
        return it

    # the static solve starts with each pair's normal force at the pressure's share
    xs = np.array([nodes[0, du] for du, _ in pairs])
    share = np.array([sum(abs(x - y) / 2 for y in xs if 0 < abs(x - y) < 1.5 * UPPER["size"][0] * UM / UPPER["elements"][0]) for x in xs])
    md.set_variable("lambda_n", -PRESSURE / 1e12 * share)
    iterations = newton()

    s_up, s_low = next((du, dl) for du, dl in pairs if abs(nodes[0, du] - SLIP_POINT[0] * UM) < 1e-6)
    corner = _at(nodes, mfu.basic_dof_on_region(U_TOP), CORNER)

    def qois():
        u, ln, lt = md.variable("u"), md.variable("lambda_n"), md.variable("lambda_t")
        # forces on the lower block (N/um of thickness, x 1e6 for N/m)
        return dict(slip=(u[s_up] - u[s_low]) / UM, force_x=-lt.sum() * 1e6, force_y=ln.sum() * 1e6,
                    corner_ux=u[corner] / UM)

    static = qois()
    slip0 = static["slip"]
    history = {q: [static[q] - (slip0 if q == "slip" else 0.0)] for q in QOIS}

    md.add_Newmark_scheme("u", beta, gamma)  # defines Dot2_u from u and the previous state
    for name, mat, region in (("u", ALU, UPPER_BODY), ("l", STEEL, LOWER_BODY)):
        md.add_initialized_data(f"rho_{name}", [mat["rho"] / 1e24])
        md.add_mass_brick(mim, "Dot2_u", f"rho_{name}", region)
    dt = DURATION / steps
    md.set_time_step(dt)
    md.set_variable("Previous_u", md.variable("u").copy())
    md.set_variable("Previous_Dot_u", np.zeros(ndof))
    md.set_variable("Previous_Dot2_u", np.zeros(ndof))  # the static state is at rest
    for n in range(1, steps + 1):
        md.set_time(n * dt)
        md.set_variable("push", [PUSH / 1e12 * n / steps, 0.0])
        md.set_variable("wt", md.variable("Previous_u"))
        iterations += newton()
        md.shift_variables_for_time_integration()
        q = qois()
        q["slip"] -= slip0
        for name in QOIS:
            history[name].append(q[name])
    final = {q: history[q][-1] for q in QOIS}
    scale = {q: max(abs(v) for v in history[q]) for q in QOIS}
    return dict(steps=steps, dt=dt, beta=beta, gamma=gamma, friction=f, r_factor=r_factor,
                final=final, scale=scale, history=history, static=static,
                rigid_estimate=rigid_estimate(f), newton_iterations=iterations,
                cpu_s=time.process_time() - cpu)



def summary(r):
    fin = r["final"]
    return (f"slip {fin['slip']:.5e} m (rigid estimate {r['rigid_estimate']:.4e}), "
            f"force_x {fin['force_x']:.5e} N/m, force_y {fin['force_y']:.5e} N/m, "
            f"corner_ux {fin['corner_ux']:.5e} m; {r['newton_iterations']} Newton iterations, "
            f"CPU {r['cpu_s']:.1f} s")


def table(results):
    """A markdown table of the final QoIs, one row per scheme and dt."""
    lines = ["| beta, gamma | dt (us) | " + " | ".join(QOIS) + " | CPU (s) |", "|---" * (len(QOIS) + 3) + "|"]
    for r in results:
        cells = " | ".join(f"{r['final'][q]:.4e}" for q in QOIS)
        lines.append(f"| {r['beta']:g}, {r['gamma']:g} | {r['dt'] * 1e6:g} | {cells} | {r['cpu_s']:.1f} |")
    return "\n".join(lines)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("mode", nargs="?", choices=["run", "table"], default="run")
    p.add_argument("--steps", type=int, default=200, help="time steps over 400 us (dt = 400 us / N)")
    p.add_argument("--beta", type=float, default=DISSIPATIVE[0])
    p.add_argument("--gamma", type=float, default=DISSIPATIVE[1])
    p.add_argument("--friction", type=float, default=FRICTION)
    p.add_argument("--r-factor", type=float, default=1.0, help="augmentation r in units of the aluminium E (nodal force per displacement)")
    p.add_argument("--json", metavar="OUT", help="write the result(s) as JSON")
    a = p.parse_args()
    opts = dict(f=a.friction, r_factor=a.r_factor)
    if not have_getfem():
        print("skipped: GetFEM (python3-getfem) is not installed for this Python "
              f"({sys.executable}); run tools/getfem/install.sh, then use /usr/bin/python3", file=sys.stderr)
        return 3
    if a.mode == "table":
        results = []
        for beta, gamma in (TRAPEZOIDAL, DISSIPATIVE):
            for n in TABLE_STEPS:
                results.append(solve(n, beta, gamma, **opts))
                print(f"beta {beta:g} gamma {gamma:g} steps {n}: {summary(results[-1])}", file=sys.stderr)
        print(table(results))
        out = results
    else:
        out = solve(a.steps, a.beta, a.gamma, **opts)
        print(summary(out))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
