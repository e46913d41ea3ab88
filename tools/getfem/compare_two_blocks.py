#!/usr/bin/env python3
"""glissade against GetFEM on two deformable blocks in frictional contact (issue 44, item 3).

The case is tools/getfem/two_blocks.py's: an aluminium block (20 x 10 mm) on a steel block
(40 x 10 mm, clamped below), pressed by 5 MPa and pushed sideways by a traction ramped to 4 MPa
over 400 us, Coulomb friction f = 0.3 between them, Newmark beta 0.3025 / gamma 0.6 in both
codes. For each dt (2, 1, 0.5, 0.25 us by default) it solves the case with GetFEM, writes it as a
glissade scene, runs `glissade-worker solve SCENE --tol T --json` on it, and prints every QoI's
final value in both codes and their difference relative to the QoI's scale (the largest
magnitude of its history, GetFEM's at the finest dt). It then says whether each code's values
moved by less than 1 % of the scale from dt / 2 to dt / 4 (time-converged), and whether the
two codes agree within 5 % on every QoI at the finest dt.

glissade's scene: a box body cannot carry a contact on part of a face (the two faces of an
interface must match node for node), so the steel block is three bodies glued by perfect
interfaces: `lower_l` (0-10 mm), `lower` (10-30 mm, under the aluminium block) and `lower_r`
(30-40 mm). The mesh is the same as GetFEM's: 2.5 mm quads in all four bodies.

GetFEM is optional (tools/getfem/install.sh; run this with /usr/bin/python3, the Python it is
installed for); without it the script says so and exits 3.

  /usr/bin/python3 tools/getfem/compare_two_blocks.py [--worker PATH] [--tol 1e-5]
          [--steps 200 400 800 1600] [--gamma 0.6] [--friction 0.3] [--keep DIR] [--json OUT.json]
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import two_blocks as tb  # noqa: E402


def rel(x, scale):
    """x relative to a QoI's scale; 0 where both are 0 (the frictionless force_x)."""
    if scale == 0:
        return 0.0 if x == 0 else float("inf")
    return x / scale

SCENE = """title = "two deformable blocks, GetFEM comparison (tools/getfem/compare_two_blocks.py)"
dimension = 2

[time]
duration = {duration}
steps = {steps}
newmark_gamma = {gamma}

[materials.steel]
E = {E_s}
nu = {nu_s}
rho = {rho_s}

[materials.al]
E = {E_a}
nu = {nu_a}
rho = {rho_a}

# the steel block, 40 x 10 mm, in three bodies glued together
[[bodies]]
name = "lower_l"
material = "steel"
size = [0.01, 0.01]
elements = [4, 4]

[[bodies]]
name = "lower"
material = "steel"
origin = [0.01, 0]
size = [0.02, 0.01]
elements = [8, 4]
substructures = [2, 1]

[[bodies]]
name = "lower_r"
material = "steel"
origin = [0.03, 0]
size = [0.01, 0.01]
elements = [4, 4]

[[bodies]]
name = "upper"
material = "al"
origin = [0.01, 0.01]
size = [0.02, 0.01]
elements = [8, 4]
substructures = [2, 1]

[[interfaces]]
name = "glue_l"
a = "lower_l.x+"
b = "lower.x-"
law = "perfect"

[[interfaces]]
name = "glue_r"
a = "lower.x+"
b = "lower_r.x-"
law = "perfect"

[[interfaces]]
name = "contact"
a = "lower.y+"
b = "upper.y-"
law = "friction"
friction = {f}

[[boundary]]
face = "lower_l.y-"
clamped = true

[[boundary]]
face = "lower.y-"
clamped = true

[[boundary]]
face = "lower_r.y-"
clamped = true

[[loads]]
face = "upper.y+"
pressure = {pressure}

[[loads]]
face = "upper.x-"
traction = [{push}, 0]
history = [[0, 0], [{duration}, 1]]

[[qoi]]
name = "slip"
kind = "slip"
interface = "contact"
point = [{slip_x}, {slip_y}]
component = "x"

[[qoi]]
name = "force_x"
kind = "force"
interface = "contact"
component = "x"

[[qoi]]
name = "force_y"
kind = "force"
interface = "contact"
component = "y"

[[qoi]]
name = "corner_ux"
kind = "displacement"
body = "upper"
point = [{corner_x}, {corner_y}]
component = "x"
"""


def scene(steps, gamma, f=tb.FRICTION):
    """The glissade scene of the case (SI), pressed from t = 0 (glissade's static stage)."""
    return SCENE.format(duration=tb.DURATION, steps=steps, gamma=gamma,
                        E_s=tb.STEEL["E"], nu_s=tb.STEEL["nu"], rho_s=tb.STEEL["rho"],
                        E_a=tb.ALU["E"], nu_a=tb.ALU["nu"], rho_a=tb.ALU["rho"], f=f,
                        pressure=tb.PRESSURE, push=tb.PUSH, slip_x=tb.SLIP_POINT[0], slip_y=tb.SLIP_POINT[1],
                        corner_x=tb.CORNER[0], corner_y=tb.CORNER[1])


def run_glissade(worker, path, tol):
    """Solves one scene; returns the QoIs' finals and histories, whether it converged (a solve
    that did not is reported, not dropped), sweeps and CPU seconds."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    res = subprocess.run([worker, "solve", path, "--tol", str(tol), "--json"], capture_output=True, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode not in (0, 2):  # 2: not converged, the report still printed
        raise RuntimeError(f"{worker} solve {path}: exit {res.returncode}\n{res.stderr[-2000:]}")
    out = json.loads(res.stdout)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    final = {q: out["qoi"][q]["final"] for q in tb.QOIS}
    history = {q: out["qoi"][q]["values"] for q in tb.QOIS}
    return dict(final=final, history=history, converged=out["converged"],
                error_estimate=out["error_estimate"], sweeps=out["dynamic_sweeps"], cpu_s=cpu)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--worker", default=os.environ.get("GLISSADE_WORKER", "target/release/glissade-worker"))
    p.add_argument("--tol", type=float, default=1e-5, help="glissade's tolerance")
    p.add_argument("--steps", type=int, nargs="+", default=[200, 400, 800, 1600], help="dt = 400 us / N")
    p.add_argument("--gamma", type=float, default=tb.DISSIPATIVE[1],
                   help="Newmark gamma of both codes (beta = (gamma + 1/2)^2 / 4)")
    p.add_argument("--friction", type=float, default=tb.FRICTION)
    p.add_argument("--keep", metavar="DIR", help="write the glissade scenes there (default: a temporary folder)")
    p.add_argument("--json", metavar="OUT", help="write every result as JSON")
    a = p.parse_args()
    if not tb.have_getfem():
        print("skipped: GetFEM (python3-getfem) is not installed for this Python "
              f"({sys.executable}); run tools/getfem/install.sh, then use /usr/bin/python3", file=sys.stderr)
        return 3
    if not os.access(a.worker, os.X_OK):
        print(f"{a.worker}: no glissade-worker there (cargo build --release, or --worker PATH)", file=sys.stderr)
        return 2
    work = a.keep or tempfile.mkdtemp(prefix="glissade-getfem-")
    os.makedirs(work, exist_ok=True)
    gamma = a.gamma
    beta = (gamma + 0.5) ** 2 / 4
    rows = []
    for n in a.steps:
        path = os.path.join(work, f"two-blocks-g{gamma:g}-f{a.friction:g}-n{n}.toml")
        with open(path, "w") as fh:
            fh.write(scene(n, gamma, a.friction))
        g = run_glissade(a.worker, path, a.tol)
        gf = tb.solve(n, beta, gamma, f=a.friction)
        rows.append(dict(steps=n, dt=tb.DURATION / n, beta=beta, gamma=gamma, friction=a.friction,
                         scene=path, glissade=g, getfem=gf))
        print(f"{n} steps: glissade {g['cpu_s']:.1f} s, {g['sweeps']:.0f} sweeps, converged {g['converged']}; "
              f"GetFEM {gf['cpu_s']:.1f} s", file=sys.stderr)

    # each QoI's scale: the largest magnitude of its history (GetFEM's, finest dt)
    finest = rows[-1]
    scale = {q: finest["getfem"]["scale"][q] for q in tb.QOIS}
    print(f"Two blocks, f = {a.friction:g}, beta {beta:g} / gamma {gamma:g}, glissade --tol {a.tol:g}. "
          f"Final values (SI: m, N/m); difference = (glissade - GetFEM) / scale.\n")
    print("| QoI (scale) | dt (us) | GetFEM | glissade | difference |")
    print("|---|---|---|---|---|")
    for q in tb.QOIS:
        for r in rows:
            g, gf = r["glissade"]["final"][q], r["getfem"]["final"][q]
            print(f"| {q} ({scale[q]:.3e}) | {r['dt'] * 1e6:g} | {gf:.4e} | {g:.4e} | {100 * rel(g - gf, scale[q]):+.2f} % |")
    print("\n| dt (us) | GetFEM CPU (s), Newton iterations | glissade CPU (s), sweeps, converged |")
    print("|---|---|---|")
    for r in rows:
        g, gf = r["glissade"], r["getfem"]
        flag = "yes" if g["converged"] else f"no (error estimate {g['error_estimate']:.1e})"
        print(f"| {r['dt'] * 1e6:g} | {gf['cpu_s']:.1f}, {gf['newton_iterations']} | {g['cpu_s']:.1f}, "
              f"{g['sweeps']:.0f}, {flag} |")

    verdict = {}
    if len(rows) >= 2:
        a2, a4 = rows[-2], rows[-1]
        print("\nChange from dt / 2 to dt / 4, relative to the scale:")
        for code in ("getfem", "glissade"):
            changes = {q: rel(a4[code]["final"][q] - a2[code]["final"][q], scale[q]) for q in tb.QOIS}
            worst = max(abs(c) for c in changes.values())
            verdict[f"{code}_converged_in_dt"] = bool(worst < 0.01)
            print(f"- {code}: " + ", ".join(f"{q} {100 * c:+.2f} %" for q, c in changes.items())
                  + f" ({'under' if worst < 0.01 else 'NOT under'} 1 %)")
    diffs = {q: rel(finest["glissade"]["final"][q] - finest["getfem"]["final"][q], scale[q]) for q in tb.QOIS}
    worst = max(abs(d) for d in diffs.values())
    verdict["agree_within_5_percent"] = bool(worst <= 0.05)
    print(f"\nAt the finest dt ({finest['dt'] * 1e6:g} us) the final values differ by at most {100 * worst:.3f} % "
          f"of a QoI's scale: {'within' if worst <= 0.05 else 'NOT within'} 5 % on every QoI.")
    # the whole histories, step by step (both codes report t_0 .. t_N)
    spans = {}
    for q in tb.QOIS:
        g, gf = finest["glissade"]["history"][q], finest["getfem"]["history"][q]
        if len(g) == len(gf):
            spans[q] = rel(max(abs(x - y) for x, y in zip(g, gf)), scale[q])
    if spans:
        print("Largest difference over the histories at the finest dt, relative to the scale: "
              + ", ".join(f"{q} {100 * v:.2f} %" for q, v in spans.items()))
    verdict["history_difference"] = spans
    # the forces in the last quarter (300-400 us, where the block slides): their mean, and the
    # standard deviation of the vibration around it, which the final value samples
    print("\nForces over the last quarter (300-400 us): mean and standard deviation (N/m)\n")
    print("| dt (us) | code | force_x mean | force_x sd | force_y mean | force_y sd |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        k0 = round(0.75 * r["steps"])
        for code in ("getfem", "glissade"):
            cells = []
            for q in ("force_x", "force_y"):
                h = r[code]["history"][q][k0:]
                mean = sum(h) / len(h)
                sd = (sum((x - mean) ** 2 for x in h) / len(h)) ** 0.5
                cells += [f"{mean:.5e}", f"{sd:.3g}"]
            print(f"| {r['dt'] * 1e6:g} | {code} | " + " | ".join(cells) + " |")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(dict(rows=rows, scale=scale, verdict=verdict), fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
