#!/usr/bin/env python3
"""The verifier's sliding block solved by GetFEM, a peer for glissade (issue 44, item 3).

The block of docs/verification.md 4d (issue 30; tools/extremes/sb_x1.toml): aluminium
(E 70e9 Pa, nu 0.33, rho 2700 kg/m^3), 30 x 15 mm in plane strain, 8 x 4 bilinear quads,
pressed on its top face by 5 MPa from t = 0 (a static solve first), pushed on its left face
by a traction ramped from 0 to 8 MPa over 600 us, Coulomb friction f = 0.4 on a rigid floor
(GetFEM's integral augmented Lagrangian brick, Alart-Curnier, option 1, integrated at the
floor's nodes: CONTACT_RULES), Newmark over 600 us
(GetFEM's own scheme, consistent mass). QoI: the x displacement of the bottom face's centre
node at 600 us, less its static value, against the rigid block's closed form
x = a (t - t*)^3 / (6 m) = 7.4074e-4 m.

Why it is written the way it is (what made earlier attempts fail):
- um-N-s units (E / 1e12, rho / 1e24) and an absolute Newton residual of 1e-10: in SI the
  residual test, scaled by the loads, declared convergence before friction had acted at all.
- The static solve starts with the contact multiplier at the pressure, not zero (from zero it
  diverges).
- Friction acts on the slip increment: its reference displacement `wt` (alpha = 1) is the
  previous step's displacement, set before each step.

GetFEM is optional: Debian's python3-getfem (tools/getfem/install.sh), imported by the system
Python, /usr/bin/python3. Without it the script says so and exits 3.

  /usr/bin/python3 tools/getfem/sliding_block.py [--steps N] [--beta B --gamma G] [--json OUT]
  /usr/bin/python3 tools/getfem/sliding_block.py table [--json OUT]
"""

import argparse
import json
import sys
import time

# The block, SI (docs/verification.md 4d; tools/extremes/sb_x1.toml).
E, NU, RHO = 70e9, 0.33, 2700.0
WIDTH, HEIGHT, NX, NY = 0.03, 0.015, 8, 4
PRESSURE, PUSH, DURATION, FRICTION = 5e6, 8e6, 6e-4, 0.4
UM = 1e6  # metres to micrometres; stresses N/um^2 = Pa / 1e12, densities / 1e24
TRAPEZOIDAL, DISSIPATIVE = (0.25, 0.5), (0.3025, 0.6)
TABLE_STEPS = (300, 600, 1200)  # dt 2, 1, 0.5 us
BOTTOM, TOP, LEFT = 1, 2, 3
# The contact's quadrature on the floor. "nodal" (Gauss-Lobatto: the edge's two end nodes) makes
# the Alart-Curnier conditions hold node by node, as glissade's do, and the answer does not depend
# on the augmentation r. "gauss" (2 points an edge, GetFEM's usual choice) satisfies them only
# weakly against the multiplier's shape functions, and on this chattering block the slip moves
# with r (README.md).
CONTACT_RULES = {"nodal": "IM_PRODUCT(IM_GAUSSLOBATTO1D(1),IM_GAUSSLOBATTO1D(1))",
                 "gauss": "IM_GAUSS_PARALLELEPIPED(2,3)"}


def closed_form(f=FRICTION):
    """The rigid block's slip at the end: x = a (T - t*)^3 / (6 m), with a the push's rate
    (N/m per s), t* when the push reaches f times the normal force, m the mass per metre."""
    mass = RHO * WIDTH * HEIGHT
    rate = PUSH * HEIGHT / DURATION
    onset = f * PRESSURE * WIDTH / rate
    return rate * max(DURATION - onset, 0.0) ** 3 / (6.0 * mass)


def solve(steps, beta=0.25, gamma=0.5, f=FRICTION, rule="nodal", r_factor=1.0, residual=1e-10, max_iter=100):
    """Static solve under the pressure, then `steps` Newmark steps; returns a dict with the
    final slip (m), its relative difference to the closed form, the CPU time and the Newton
    iterations."""
    import getfem as gf
    import numpy as np

    gf.util_trace_level(0)
    cpu = time.process_time()
    m = gf.Mesh("cartesian", np.linspace(0, WIDTH * UM, NX + 1), np.linspace(0, HEIGHT * UM, NY + 1))
    faces = m.outer_faces()
    normals = m.normal_of_faces(faces)
    m.set_region(BOTTOM, faces[:, normals[1] < -0.5])
    m.set_region(TOP, faces[:, normals[1] > 0.5])
    m.set_region(LEFT, faces[:, normals[0] < -0.5])
    mfu = gf.MeshFem(m, 2)
    mfu.set_fem(gf.Fem("FEM_QK(2,1)"))
    mfd = gf.MeshFem(m, 1)
    mfd.set_fem(gf.Fem("FEM_QK(2,1)"))
    mim = gf.MeshIm(m, gf.Integ("IM_GAUSS_PARALLELEPIPED(2,3)"))  # 2 x 2 points, 2 per edge

    e, rho = E / 1e12, RHO / 1e24
    md = gf.Model("real")
    md.add_fem_variable("u", mfu)
    md.add_initialized_data("lambda", [e * NU / ((1 + NU) * (1 - 2 * NU))])  # plane strain
    md.add_initialized_data("mu", [e / (2 * (1 + NU))])
    md.add_isotropic_linearized_elasticity_brick(mim, "u", "lambda", "mu")
    md.add_initialized_data("top", [0.0, -PRESSURE / 1e12])
    md.add_source_term_brick(mim, "u", "top", TOP)
    md.add_initialized_data("push", [0.0, 0.0])
    md.add_source_term_brick(mim, "u", "push", LEFT)

    # Frictional contact with the floor y = 0: a vector multiplier (the contact stress) on the
    # bottom face's nodes; friction on alpha (u - wt), the slip since the previous step.
    mfl = gf.MeshFem(m, 2)
    mfl.set_fem(gf.Fem("FEM_QK(2,1)"))
    mfl = gf.MeshFem("partial", mfl, mfl.basic_dof_on_region(BOTTOM))
    md.add_fem_variable("lambda_c", mfl)
    md.add_initialized_fem_data("obstacle", mfd, mfd.eval("y"))
    md.add_initialized_data("r", [r_factor * e / (HEIGHT * UM / NY)])  # augmentation E / h
    md.add_initialized_data("f", [f])
    md.add_initialized_data("alpha", [1.0])
    md.add_initialized_fem_data("wt", mfu, np.zeros(mfu.nbdof()))
    mimc = gf.MeshIm(m, gf.Integ(CONTACT_RULES[rule]))
    md.add_integral_contact_with_rigid_obstacle_brick(
        mimc, "u", "lambda_c", "obstacle", "r", "f", BOTTOM, 1, "alpha", "wt")

    def newton():
        it, converged = md.solve("max_res", residual, "max_iter", max_iter, "lsearch", "basic")  # "default" stalls at landings
        if not converged:
            raise RuntimeError(f"Newton did not converge in {max_iter} iterations")
        return it

    lam = np.zeros(mfl.nbdof())
    lam[1::2] = PRESSURE / 1e12  # the contact stress on the body: (0, +p)
    md.set_variable("lambda_c", lam)
    iterations = newton()
    u_static = md.variable("u").copy()

    centre = [i for i, (x, y) in enumerate(mfu.basic_dof_nodes().T)
              if abs(x - WIDTH * UM / 2) < 1e-6 and abs(y) < 1e-6][0]  # its x dof (first)

    md.add_initialized_data("rho", [rho])
    md.add_Newmark_scheme("u", beta, gamma)  # defines Dot2_u from u and the previous state
    md.add_mass_brick(mim, "Dot2_u", "rho")
    dt = DURATION / steps
    md.set_time_step(dt)
    md.set_variable("Previous_u", u_static)
    md.set_variable("Previous_Dot_u", np.zeros(mfu.nbdof()))
    md.set_variable("Previous_Dot2_u", np.zeros(mfu.nbdof()))  # the static state is at rest
    for n in range(1, steps + 1):
        md.set_time(n * dt)
        md.set_variable("push", [PUSH / 1e12 * n / steps, 0.0])
        md.set_variable("wt", md.variable("Previous_u"))
        iterations += newton()
        md.shift_variables_for_time_integration()
    slip = (md.variable("u")[centre] - u_static[centre]) / UM
    ref = closed_form(f)
    return dict(steps=steps, dt=dt, beta=beta, gamma=gamma, friction=f, contact_rule=rule,
                r_factor=r_factor, slip=slip,
                closed_form=ref, rel_diff=slip / ref - 1.0, newton_iterations=iterations,
                cpu_s=time.process_time() - cpu)


def have_getfem():
    try:
        import getfem  # noqa: F401
        return True
    except ImportError:
        return False


def table(results):
    """A markdown table of the slips' differences to the closed form, one row per scheme."""
    schemes = sorted({(r["beta"], r["gamma"]) for r in results}, key=lambda s: s[1])
    steps = sorted({r["steps"] for r in results})
    head = "| scheme (beta, gamma) | " + " | ".join(f"dt {DURATION / n * 1e6:g} us" for n in steps) + " |"
    lines = [head, "|---" * (len(steps) + 1) + "|"]
    for b, g in schemes:
        cells = []
        for n in steps:
            r = next(r for r in results if (r["beta"], r["gamma"], r["steps"]) == (b, g, n))
            cells.append(f"{r['slip']:.4e} ({100 * r['rel_diff']:+.2f} %, {r['cpu_s']:.1f} s)")
        lines.append(f"| {b:g}, {g:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + f"\n\nclosed form {closed_form():.4e} m"


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("mode", nargs="?", choices=["run", "table"], default="run")
    p.add_argument("--steps", type=int, default=300, help="time steps over 600 us (dt = 600 us / N)")
    p.add_argument("--beta", type=float, default=TRAPEZOIDAL[0])
    p.add_argument("--gamma", type=float, default=TRAPEZOIDAL[1])
    p.add_argument("--friction", type=float, default=FRICTION)
    p.add_argument("--contact-rule", choices=sorted(CONTACT_RULES), default="nodal")
    p.add_argument("--r-factor", type=float, default=1.0, help="augmentation r in units of E / h")
    p.add_argument("--json", metavar="OUT", help="write the result(s) as JSON")
    a = p.parse_args()
    opts = dict(f=a.friction, rule=a.contact_rule, r_factor=a.r_factor)
    if not have_getfem():
        print("skipped: GetFEM (python3-getfem) is not installed for this Python "
              f"({sys.executable}); run tools/getfem/install.sh, then use /usr/bin/python3", file=sys.stderr)
        return 3
    if a.mode == "table":
        results = []
        for beta, gamma in (TRAPEZOIDAL, DISSIPATIVE):
            for n in TABLE_STEPS:
                results.append(solve(n, beta, gamma, **opts))
                r = results[-1]
                print(f"beta {beta:g} gamma {gamma:g} steps {n}: slip {r['slip']:.5e} m "
                      f"({100 * r['rel_diff']:+.2f} %), {r['cpu_s']:.1f} s", file=sys.stderr)
        print(table(results))
        out = results
    else:
        out = solve(a.steps, a.beta, a.gamma, **opts)
        print(f"slip {out['slip']:.5e} m, closed form {out['closed_form']:.5e} m "
              f"({100 * out['rel_diff']:+.2f} %), {out['newton_iterations']} Newton iterations, "
              f"CPU {out['cpu_s']:.1f} s")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
