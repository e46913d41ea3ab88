#!/usr/bin/env python3
"""glissade against GetFEM on the verifier's sliding block, same scheme, same dt (issue 44).

For each Newmark scheme (trapezoidal beta 0.25 / gamma 0.5; dissipative beta 0.3025 / gamma
0.6, glissade's beta = (gamma + 1/2)^2 / 4) and each dt (2, 1, 0.5 us), solves the block of
tools/getfem/sliding_block.py with GetFEM and writes the same block as a glissade scene (the
block of tools/extremes/sb_x1.toml, with `steps` and `newmark_gamma`), runs
`glissade-worker solve SCENE --tol T --json` on it and reads `qoi.slip.final`; prints both
slips and their differences to the rigid closed form side by side (markdown), with CPU times.

GetFEM is optional (tools/getfem/install.sh; run this with /usr/bin/python3, the Python it is
installed for); without it the script says so and exits 3.

  /usr/bin/python3 tools/getfem/compare.py [--worker PATH] [--tol 1e-5] [--steps 300 600 1200]
          [--keep DIR] [--json OUT.json]
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import sliding_block as sb  # noqa: E402

SCENE = """title = "verifier sliding block, GetFEM comparison (tools/getfem/compare.py)"
dimension = 2

[time]
duration = {duration}
steps = {steps}
newmark_gamma = {gamma}

[materials.al]
E = {E}
nu = {nu}
rho = {rho}

[[bodies]]
name = "block"
material = "al"
size = [{width}, {height}]
elements = [{nx}, {ny}]
substructures = [2, 1]

[[interfaces]]
name = "floor"
a = "block.y-"
b = "wall"
law = "friction"
friction = {f}

[[loads]]
face = "block.y+"
pressure = {pressure}

[[loads]]
face = "block.x-"
traction = [{push}, 0]
history = [[0, 0], [{duration}, 1]]

[[qoi]]
name = "slip"
kind = "slip"
interface = "floor"
point = [{centre}, 0]
"""


def scene(steps, gamma, f=sb.FRICTION):
    """The glissade scene of the block (SI), pressed from t = 0 (glissade's static stage)."""
    return SCENE.format(duration=sb.DURATION, steps=steps, gamma=gamma, E=sb.E, nu=sb.NU, rho=sb.RHO,
                        width=sb.WIDTH, height=sb.HEIGHT, nx=sb.NX, ny=sb.NY, f=f,
                        pressure=sb.PRESSURE, push=sb.PUSH, centre=sb.WIDTH / 2)


def run_glissade(worker, path, tol):
    """Solves one scene; returns the final slip, whether it converged (a solve that did not is
    reported with its slip and error estimate, not dropped), sweeps and CPU seconds."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    res = subprocess.run([worker, "solve", path, "--tol", str(tol), "--json"], capture_output=True, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode not in (0, 2):  # 2: not converged, the report still printed
        raise RuntimeError(f"{worker} solve {path}: exit {res.returncode}\n{res.stderr[-2000:]}")
    out = json.loads(res.stdout)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return dict(slip=out["qoi"]["slip"]["final"], converged=out["converged"],
                error_estimate=out["error_estimate"], sweeps=out["dynamic_sweeps"], cpu_s=cpu)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--worker", default=os.environ.get("GLISSADE_WORKER", "target/release/glissade-worker"))
    p.add_argument("--tol", type=float, default=1e-5, help="glissade's tolerance")
    p.add_argument("--steps", type=int, nargs="+", default=list(sb.TABLE_STEPS))
    p.add_argument("--keep", metavar="DIR", help="write the glissade scenes there (default: a temporary folder)")
    p.add_argument("--json", metavar="OUT", help="write every result as JSON")
    a = p.parse_args()
    if not sb.have_getfem():
        print("skipped: GetFEM (python3-getfem) is not installed for this Python "
              f"({sys.executable}); run tools/getfem/install.sh, then use /usr/bin/python3", file=sys.stderr)
        return 3
    if not os.access(a.worker, os.X_OK):
        print(f"{a.worker}: no glissade-worker there (cargo build --release, or --worker PATH)", file=sys.stderr)
        return 2
    work = a.keep or tempfile.mkdtemp(prefix="glissade-getfem-")
    os.makedirs(work, exist_ok=True)
    ref = sb.closed_form()
    rows = []
    for beta, gamma in (sb.TRAPEZOIDAL, sb.DISSIPATIVE):
        for n in a.steps:
            path = os.path.join(work, f"sliding-block-g{gamma:g}-n{n}.toml")
            with open(path, "w") as fh:
                fh.write(scene(n, gamma))
            g = run_glissade(a.worker, path, a.tol)
            gf = sb.solve(n, beta, gamma)
            rows.append(dict(beta=beta, gamma=gamma, steps=n, dt=sb.DURATION / n, closed_form=ref,
                             glissade=g, getfem=gf))
            print(f"gamma {gamma:g}, {n} steps: glissade {g['slip']:.5e} m ({g['cpu_s']:.1f} s), "
                  f"GetFEM {gf['slip']:.5e} m ({gf['cpu_s']:.1f} s)", file=sys.stderr)
    print(f"Final slip (m) and difference to the rigid closed form {ref:.4e} m; CPU seconds\n")
    print("| scheme | dt (us) | GetFEM | glissade | glissade - GetFEM |")
    print("|---|---|---|---|---|")
    for r in rows:
        g, gf = r["glissade"], r["getfem"]
        name = "trapezoidal" if r["gamma"] == 0.5 else f"beta {r['beta']:g}, gamma {r['gamma']:g}"
        flag = "" if g["converged"] else f", not converged: error estimate {g['error_estimate']:.1e}"
        print(f"| {name} | {r['dt'] * 1e6:g} | {gf['slip']:.4e} ({100 * (gf['slip'] / ref - 1):+.2f} %, "
              f"{gf['cpu_s']:.1f} s) | {g['slip']:.4e} ({100 * (g['slip'] / ref - 1):+.2f} %, {g['cpu_s']:.1f} s, "
              f"{g['sweeps']:.0f} sweeps{flag}) | {100 * (g['slip'] - gf['slip']) / ref:+.2f} % |")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
