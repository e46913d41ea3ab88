#!/usr/bin/env python3
"""Validate glissade against CalculiX (ccx) on a box-bodied 3D scene (docs/verification.md 12).

Writes a CalculiX input deck of the scene at one design point (the same hex8 mesh per body,
materials, boundary conditions, surface loads with their histories, frictional contact as
surface-to-surface penalty contact), runs ccx, reads the QoI nodes' displacements from its .dat
file, runs `glissade-worker solve --json` on the same scene (optionally at another number of
steps), and compares the QoI histories: relative L2 over the history and the final values.

Python 3.11+ standard library only. CalculiX is optional (Debian: `apt-get install calculix-ccx`);
without it `run` says so and exits 3, `deck` still writes the deck.

  python3 tools/calculix/compare.py deck SCENE [--set NAME=VALUE]... --dt DT -o DECK.inp
  python3 tools/calculix/compare.py run SCENE [--set NAME=VALUE]... --ccx-dt DT --glissade-steps N
          [--tol T] [--worker PATH] [--workdir DIR] [--json OUT.json]
  python3 tools/calculix/compare.py kt-limit RUN.json RUN.json... --glissade-json G.json
  (--kt, --alpha and --contact set the deck's contact: docs/verification.md 12)

What the deck models, and why (issue 29's measurements):
- C3D8 elements (8-node hexahedra, ccx's default integration); glissade integrates the volumetric
  part at the centre (docs/method.md 2): a mesh difference that does not fall with dt.
- Contact: surface-to-surface penalty, linear pressure-overclosure of slope --kn (3e15 Pa/m),
  Coulomb friction with stick slope --kt (3e13 Pa/m: K / 100, the CalculiX manual's advice).
  ccx's node-to-surface contact returned wrong answers with exit code 0 on this scene, and
  surface-to-surface with fixed increments could hang: the dynamic step uses automatic increments
  capped at the step asked. The stick slope is an elastic slip glissade does not have (its stick
  is rigid): up to f p / kt where the interface sticks (docs/verification.md 12 says how much).
  `--contact mortar` (and the other mortar kinds, HARD: Lagrange multipliers, a rigid stick)
  writes ccx's mortar contact instead; ccx 2.20 crashes with it in a dynamic step.
- A static step first (the prescribed displacements and the loads' values at t = 0, as glissade's
  static prestress stage), then an implicit dynamic step over the scene's duration, with ccx's
  default Hilber-Hughes-Taylor alpha = -0.05 (second order; it damps the highest modes a little);
  alpha = 0 (Newmark's average acceleration, glissade's scheme) did not get through the slip
  onsets of three-blocks-small (docs/verification.md 12).
- QoIs: `displacement` (a body node's component) and `slip` (the tangential relative displacement,
  side b less side a, accumulated during the dynamics: less its value at the static step's end),
  at the nodes nearest the QoI points as glissade picks them (docs/scenes.md, [[qoi]]).
"""

import argparse
import json
import math
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib

AXES = "xyz"
# C3D8 face labels for a box element whose nodes 1-4 are the z- face counter-clockwise from the
# lowest corner and 5-8 the z+ face above them (ccx manual, C3D8 faces).
FACE_LABEL = {"z-": "S1", "z+": "S2", "y-": "S3", "x+": "S4", "y+": "S5", "x-": "S6"}
# Faces that start exactly touching flip between open and closed at round-off, and sticking
# points flip with slipping ones: ccx's default test on the contact elements (converged when
# their number changes by less than 0.1 %) then never passes and the increment is cut back
# until ccx stops. 5 % lets the equilibrium residual decide.
CONTACT_CONTROLS = "*CONTROLS, PARAMETERS=CONTACT\n0.05"
LOAD_LABEL = {k: "P" + v[1] for k, v in FACE_LABEL.items()}


class SceneError(Exception):
    """A scene this script cannot write as a CalculiX deck (the message says why)."""


def parse_set(items):
    out = {}
    for s in items:
        name, sep, value = s.partition("=")
        if not sep:
            raise SceneError(f"--set {s}: write NAME=VALUE")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise SceneError(f"--set {s}: {value!r} is not a number") from None
    return out


class Scene:
    """The parts of a glissade scene (docs/scenes.md) a deck needs, at one design point."""

    def __init__(self, text, values):
        self.raw = tomllib.loads(text)
        s = self.raw
        if s.get("dimension") != 3:
            raise SceneError("dimension: only 3D scenes (hex8 bodies) are written as CalculiX decks")
        params = {k: float(v["default"]) for k, v in s.get("parameters", {}).items()}
        for k, v in values.items():
            if k not in params:
                raise SceneError(f"--set {k}: the scene has no parameter {k!r}")
            params[k] = v
        self.params = params
        t = s["time"]
        self.duration = self.value(t["duration"], "time.duration")
        self.steps = int(t["steps"])
        if t.get("mass", "consistent") != "consistent":
            raise SceneError("time.mass: only the consistent mass (ccx's) is compared")
        self.materials = {}
        for name, m in s["materials"].items():
            self.materials[name] = tuple(self.value(m[k], f"materials.{name}.{k}") for k in ("E", "nu", "rho"))
        self.bodies = []
        for i, b in enumerate(s["bodies"]):
            if "mesh" in b:
                raise SceneError(f"bodies[{i}]: a Gmsh body; only generated boxes are written")
            if b["material"] not in self.materials:
                raise SceneError(f"bodies[{i}].material: unknown material {b['material']!r}")
            origin = [self.value(x, f"bodies[{i}].origin") for x in b.get("origin", [0, 0, 0])]
            size = [self.value(x, f"bodies[{i}].size") for x in b["size"]]
            if "initial_velocity" in b:
                raise SceneError(f"bodies[{i}].initial_velocity: not written to the deck")
            self.bodies.append(dict(name=b["name"], material=b["material"], origin=origin, size=size,
                                    elements=[int(n) for n in b["elements"]]))
        self.body_index = {b["name"]: i for i, b in enumerate(self.bodies)}
        self.interfaces = []
        for i, itf in enumerate(s.get("interfaces", [])):
            law = itf.get("law")
            if law not in ("friction", "contact"):
                raise SceneError(f"interfaces[{i}].law = {law!r}: only contact and friction between bodies")
            if "b" not in itf:
                raise SceneError(f"interfaces[{i}]: a wall; only interfaces between two bodies")
            f = self.value(itf.get("friction", 0.0), f"interfaces[{i}].friction") if law == "friction" else 0.0
            self.interfaces.append(dict(name=itf["name"], a=self.face(itf["a"]), b=self.face(itf["b"]), friction=f))
        self.interface_index = {x["name"]: i for i, x in enumerate(self.interfaces)}
        self.boundary = []
        for i, bc in enumerate(s.get("boundary", [])):
            if "velocity" in bc:
                raise SceneError(f"boundary[{i}].velocity: prescribed velocities are not written")
            disp = {}
            if bc.get("clamped"):
                disp = {c: 0.0 for c in AXES}
            for c, v in bc.get("displacement", {}).items():
                disp[c] = self.value(v, f"boundary[{i}].displacement.{c}")
            self.boundary.append((self.face(bc["face"]), disp))
        self.loads = []
        for i, ld in enumerate(s.get("loads", [])):
            if "pressure" not in ld:
                raise SceneError(f"loads[{i}]: only pressures are written")
            hist = [(self.value(a, f"loads[{i}].history"), self.value(b, f"loads[{i}].history"))
                    for a, b in ld.get("history", [[0.0, 1.0]])]
            self.loads.append((self.face(ld["face"]), self.value(ld["pressure"], f"loads[{i}].pressure"), hist))
        self.qois = []
        for i, q in enumerate(s.get("qoi", [])):
            kind = q["kind"]
            point = [self.value(x, f"qoi[{i}].point") for x in q["point"]]
            comp = q.get("component")
            if kind == "displacement":
                self.qois.append(dict(name=q["name"], kind=kind, body=self.body_index[q["body"]], point=point,
                                      component=AXES.index(comp)))
            elif kind == "slip":
                if q["interface"] not in self.interface_index:
                    raise SceneError(f"qoi[{i}].interface: unknown interface {q['interface']!r}")
                self.qois.append(dict(name=q["name"], kind=kind, interface=self.interface_index[q["interface"]],
                                      point=point, component=None if comp is None else AXES.index(comp)))
            else:
                raise SceneError(f"qoi[{i}].kind = {kind!r}: only displacement and slip are compared")

    def value(self, v, key):
        if isinstance(v, (int, float)):
            return float(v)
        if isinstance(v, str):
            neg = v.startswith("-")
            name = v[1:] if neg else v
            if name not in self.params:
                raise SceneError(f"{key}: undeclared parameter {name!r}")
            return -self.params[name] if neg else self.params[name]
        raise SceneError(f"{key}: expected a number or a parameter name, got {v!r}")

    def face(self, spec):
        body, _, face = spec.partition(".")
        if body not in self.body_index or face not in FACE_LABEL:
            raise SceneError(f"face {spec!r}: expected BODY.FACE of a box body (x-, x+, y-, y+, z-, z+)")
        return self.body_index[body], face


class Mesh:
    """Every body's structured hex8 mesh, numbered body after body (nodes and elements from 1)."""

    def __init__(self, scene):
        self.nodes = []  # (x, y, z)
        self.elements = []  # (body, [8 node ids])
        self.first_node = []
        self.first_element = []
        for b in scene.bodies:
            nx, ny, nz = b["elements"]
            n0 = len(self.nodes) + 1
            self.first_node.append(n0)
            self.first_element.append(len(self.elements) + 1)
            for k in range(nz + 1):
                for j in range(ny + 1):
                    for i in range(nx + 1):
                        self.nodes.append(tuple(b["origin"][a] + b["size"][a] * (i, j, k)[a] / b["elements"][a]
                                                for a in range(3)))

            def nid(i, j, k, nx=nx, ny=ny, n0=n0):
                return n0 + i + (nx + 1) * (j + (ny + 1) * k)

            for k in range(nz):
                for j in range(ny):
                    for i in range(nx):
                        self.elements.append((len(self.first_node) - 1, [
                            nid(i, j, k), nid(i + 1, j, k), nid(i + 1, j + 1, k), nid(i, j + 1, k),
                            nid(i, j, k + 1), nid(i + 1, j, k + 1), nid(i + 1, j + 1, k + 1), nid(i, j + 1, k + 1)]))
        self.scene = scene

    def grid(self, body):
        b = self.scene.bodies[body]
        return b["elements"]

    def face_nodes(self, body, face):
        nx, ny, nz = self.grid(body)
        axis, side = AXES.index(face[0]), face[1]
        out = []
        for k in range(nz + 1):
            for j in range(ny + 1):
                for i in range(nx + 1):
                    ijk = (i, j, k)
                    if ijk[axis] == (0 if side == "-" else (nx, ny, nz)[axis]):
                        out.append(self.first_node[body] + i + (nx + 1) * (j + (ny + 1) * k))
        return out

    def face_elements(self, body, face):
        nx, ny, nz = self.grid(body)
        axis, side = AXES.index(face[0]), face[1]
        out = []
        e = self.first_element[body]
        for k in range(nz):
            for j in range(ny):
                for i in range(nx):
                    if (i, j, k)[axis] == (0 if side == "-" else (nx, ny, nz)[axis] - 1):
                        out.append(e)
                    e += 1
        return out

    def nearest(self, candidates, point):
        return min(candidates, key=lambda n: sum((self.nodes[n - 1][a] - point[a]) ** 2 for a in range(3)))


def fmt(x):
    return f"{x:.12e}"


def lines(ids, per=8):
    return "\n".join(", ".join(str(i) for i in ids[k:k + per]) for k in range(0, len(ids), per))


def qoi_nodes(scene, mesh):
    """Per QoI, the nodes it reads: (node,) for a displacement, (node on a, node on b) for a slip."""
    out = []
    for q in scene.qois:
        if q["kind"] == "displacement":
            b = scene.bodies[q["body"]]
            cand = range(mesh.first_node[q["body"]], mesh.first_node[q["body"]] + math.prod(n + 1 for n in b["elements"]))
            out.append((mesh.nearest(cand, q["point"]),))
        else:
            itf = scene.interfaces[q["interface"]]
            na = mesh.nearest(mesh.face_nodes(*itf["a"]), q["point"])
            nb = mesh.nearest(mesh.face_nodes(*itf["b"]), mesh.nodes[na - 1])
            if math.dist(mesh.nodes[na - 1], mesh.nodes[nb - 1]) > 1e-9 * max(scene.bodies[0]["size"]):
                raise SceneError(f"qoi {q['name']}: the interface's meshes are not conforming at the point")
            out.append((na, nb))
    return out


def write_deck(scene, mesh, dt, kn, kt, alpha, title, contact="penalty"):
    """The CalculiX input deck (text)."""
    out = [f"*HEADING\n{title}"]
    out.append("*NODE, NSET=NALL")
    out += [f"{i + 1}, {fmt(x)}, {fmt(y)}, {fmt(z)}" for i, (x, y, z) in enumerate(mesh.nodes)]
    for bi, b in enumerate(scene.bodies):
        out.append(f"*ELEMENT, TYPE=C3D8, ELSET=E_{b['name']}")
        e0 = mesh.first_element[bi]
        out += [f"{e0 + k}, " + ", ".join(map(str, conn))
                for k, (body, conn) in enumerate(x for x in mesh.elements if x[0] == bi)]
    for name, (E, nu, rho) in scene.materials.items():
        out.append(f"*MATERIAL, NAME=M_{name}\n*ELASTIC\n{fmt(E)}, {fmt(nu)}\n*DENSITY\n{fmt(rho)}")
    for b in scene.bodies:
        out.append(f"*SOLID SECTION, ELSET=E_{b['name']}, MATERIAL=M_{b['material']}")

    def surface(body, face):
        name = f"S_{scene.bodies[body]['name']}_{face.replace('-', 'm').replace('+', 'p')}"
        if name not in made:
            made.add(name)
            out.append(f"*SURFACE, NAME={name}, TYPE=ELEMENT")
            out.extend(f"{e}, {FACE_LABEL[face]}" for e in mesh.face_elements(body, face))
        return name

    def nset(body, face):
        name = f"N_{scene.bodies[body]['name']}_{face.replace('-', 'm').replace('+', 'p')}"
        if name not in made:
            made.add(name)
            out.append(f"*NSET, NSET={name}")
            out.append(lines(mesh.face_nodes(body, face)))
        return name

    made = set()
    for i, itf in enumerate(scene.interfaces):
        slave, master = surface(*itf["a"]), surface(*itf["b"])
        behavior = "LINEAR\n" + fmt(kn) if contact == "penalty" else "HARD"
        out.append(f"*SURFACE INTERACTION, NAME=I_{i}\n*SURFACE BEHAVIOR, PRESSURE-OVERCLOSURE={behavior}")
        if itf["friction"] > 0:
            out.append(f"*FRICTION\n{fmt(itf['friction'])}, {fmt(kt)}")
        # the slave: the side whose material expands less across the interface under the normal
        # load (lower nu); its face then stays within the master's (an integration point of the
        # slave beyond the master's edge chatters in and out of contact)
        if scene.materials[scene.bodies[itf["b"][0]]["material"]][1] < scene.materials[scene.bodies[itf["a"][0]]["material"]][1]:
            slave, master = master, slave
        kind = "SURFACE TO SURFACE" if contact == "penalty" else contact.upper()
        out.append(f"*CONTACT PAIR, INTERACTION=I_{i}, TYPE={kind}\n"
                   f"{slave}, {master}")
    qn = sorted({n for t in qoi_nodes(scene, mesh) for n in t})
    out.append("*NSET, NSET=N_QOI\n" + lines(qn))
    loads = []
    for j, (face, p, hist) in enumerate(scene.loads):
        name = f"E_load{j}"
        out.append(f"*ELSET, ELSET={name}\n" + lines(mesh.face_elements(*face)))
        f0 = interpolate([h[0] for h in hist], [h[1] for h in hist], 0.0)
        # the history as a step-time amplitude, flat beyond its ends as glissade's
        pts = ([(0.0, hist[0][1])] if hist[0][0] > 0.0 else []) + [h for h in hist if h[0] >= 0.0]
        if hist[0][0] < 0.0:
            pts.insert(0, (0.0, f0))
        pts.append((max(hist[-1][0], scene.duration) + 1.0, hist[-1][1]))
        out.append(f"*AMPLITUDE, NAME=A_load{j}\n" + "\n".join(f"{fmt(t)}, {fmt(f)}" for t, f in pts))
        loads.append((name, LOAD_LABEL[face[1]], p, f0, j))
    bcs = []
    for face, disp in scene.boundary:
        ns = nset(*face)
        for c, v in disp.items():
            a = AXES.index(c) + 1
            bcs.append(f"{ns}, {a}, {a}, {fmt(v)}")
    # output times of the dynamics (ccx wants them before the first step): every dt
    n_out = round(scene.duration / dt)
    out.append(f"*TIME POINTS, NAME=T_OUT, GENERATE\n{fmt(dt)}, {fmt(n_out * dt)}, {fmt(dt)}")
    # static prestress stage: boundary displacements and the loads' values at t = 0
    out.append("*STEP, INC=1000\n*STATIC\n0.1, 1.0, 1e-5, 0.25")
    out.append(CONTACT_CONTROLS)
    out.append("*BOUNDARY\n" + "\n".join(bcs))
    for name, label, p, f0, _ in loads:
        if f0 != 0.0:
            out.append(f"*DLOAD\n{name}, {label}, {fmt(p * f0)}")
    # energies: ccx's nonlinear dynamics wants them selected from the first step on
    out.append("*NODE PRINT, NSET=N_QOI\nU\n*EL FILE\nENER\n*END STEP")
    # dynamics: Newmark average acceleration, increments at most dt; every dt printed
    out.append(f"*STEP, INC=1000000\n*DYNAMIC, ALPHA={alpha}\n{fmt(dt)}, {fmt(scene.duration)}, {fmt(dt * 1e-4)}, {fmt(dt)}")
    out.append(CONTACT_CONTROLS)
    for name, label, p, _, j in loads:
        out.append(f"*DLOAD, AMPLITUDE=A_load{j}\n{name}, {label}, {fmt(p)}")
    out.append("*NODE PRINT, NSET=N_QOI, TIME POINTS=T_OUT\nU\n*END STEP\n")
    return "\n".join(out)


def interpolate(xs, ys, x):
    if x <= xs[0]:
        return ys[0]
    for k in range(1, len(xs)):
        if x <= xs[k]:
            if xs[k] == xs[k - 1]:
                return ys[k]
            w = (x - xs[k - 1]) / (xs[k] - xs[k - 1])
            return ys[k - 1] + w * (ys[k] - ys[k - 1])
    return ys[-1]


def read_dat(path):
    """The displacement blocks of a ccx .dat file: [(total time, {node: (ux, uy, uz)})]."""
    blocks = []
    head = re.compile(r"^\s*displacements \(vx,vy,vz\) for set \S+ and time\s+(\S+)")
    cur = None
    with open(path) as f:
        for line in f:
            m = head.match(line)
            if m:
                cur = {}
                blocks.append((float(m.group(1)), cur))
                continue
            parts = line.split()
            if cur is not None and len(parts) == 4 and parts[0].isdigit():
                cur[int(parts[0])] = tuple(float(x) for x in parts[1:])
            elif cur is not None and parts and not parts[0].isdigit():
                cur = None
    return blocks


def ccx_histories(scene, mesh, blocks):
    """Per QoI, (times, values) of the dynamics from ccx's blocks (static step: total time <= 1)."""
    static = [b for t, b in blocks if t <= 1.0 + 1e-9]
    dyn = [(t - 1.0, b) for t, b in blocks if t > 1.0 + 1e-9]
    if not static or not dyn:
        raise RuntimeError("ccx's .dat has no static or no dynamic displacement output (did it converge?)")
    u0 = static[-1]
    times = [0.0] + [t for t, _ in dyn]
    out = {}
    for q, nodes in zip(scene.qois, qoi_nodes(scene, mesh)):
        vals = []
        for b in [u0] + [b for _, b in dyn]:
            if q["kind"] == "displacement":
                vals.append(b[nodes[0]][q["component"]])
            else:
                na, nb = nodes
                rel = [(b[nb][c] - b[na][c]) - (u0[nb][c] - u0[na][c]) for c in range(3)]
                n = normal(scene.interfaces[q["interface"]]["a"][1])
                rn = sum(rel[c] * n[c] for c in range(3))
                tan = [rel[c] - rn * n[c] for c in range(3)]
                vals.append(tan[q["component"]] if q["component"] is not None else math.sqrt(sum(x * x for x in tan)))
        out[q["name"]] = (times, vals)
    return out


def normal(face):
    n = [0.0, 0.0, 0.0]
    n[AXES.index(face[0])] = 1.0 if face[1] == "+" else -1.0
    return n


def compare(a, b):
    """Relative L2 difference of history a from the reference b, ||a - b|| / ||b||, over the
    coarser history's times (the finer one read there: exact where the steps nest, as 1 us in
    2 us), and the finals' relative difference (a - b) / |b|."""
    coarse = a[0] if len(a[0]) <= len(b[0]) else b[0]
    va = [interpolate(a[0], a[1], t) for t in coarse]
    vb = [interpolate(b[0], b[1], t) for t in coarse]
    l2 = math.sqrt(sum((x - y) ** 2 for x, y in zip(va, vb))) / max(math.sqrt(sum(y * y for y in vb)), 1e-300)
    fin = (a[1][-1] - b[1][-1]) / abs(b[1][-1]) if b[1][-1] != 0 else float("inf")
    return l2, fin


def with_steps(text, steps):
    """The scene text with [time] steps replaced (the rest as written, so hashes stay readable)."""
    out, section, done = [], None, False
    for line in text.splitlines(keepends=True):
        m = re.match(r"^\s*\[+\s*([^\]]+?)\s*\]+", line)
        if m:
            section = m.group(1)
        if section == "time" and not done and re.match(r"^\s*steps\s*=", line):
            line = f"steps = {steps}\n"
            done = True
        out.append(line)
    if not done:
        raise SceneError("[time] steps: not found in the scene text")
    return "".join(out)


def kt_limit(runs):
    """ccx's QoI histories extrapolated to a rigid stick (kt -> infinity) from runs at several
    stick slopes: the penalty's elastic slip is tau / kt, linear in 1 / kt while the contact
    states stay those of the runs, so q(kt) = q_inf + c / kt; with two runs q_inf is the line's
    value at 1 / kt = 0, with three the two stiffest give it and the two softest say how straight
    the line is. Runs are `run --json` outputs of one scene and point; the histories are compared
    at the coarsest run's times. Returns (kts, {qoi: (times, extrapolated, from the softest pair)})."""
    runs = sorted(runs, key=lambda r: -r["kt"])
    kts = [r["kt"] for r in runs]
    if len(runs) < 2 or len(set(kts)) != len(kts):
        raise SceneError("kt-limit: two or more runs at different --kt")
    out = {}
    for name in runs[0]["ccx"]:
        hs = [(r["ccx"][name]["times"], r["ccx"][name]["values"]) for r in runs]
        end = min(h[0][-1] for h in hs)
        times = [t for t in min((h[0] for h in hs), key=len) if t <= end * (1 + 1e-12)]
        vals = [[interpolate(h[0], h[1], t) for t in times] for h in hs]

        def line(i, j):
            xi, xj = 1.0 / kts[i], 1.0 / kts[j]
            return [(vi * xj - vj * xi) / (xj - xi) for vi, vj in zip(vals[i], vals[j])]
        out[name] = (times, line(0, 1), line(len(runs) - 2, len(runs) - 1))
    return kts, out


def child_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    lim = sub.add_parser("kt-limit", help="ccx runs at several --kt extrapolated to a rigid stick, against glissade")
    lim.add_argument("runs", nargs="+", metavar="RUN.json", help="`run --json` outputs at different --kt")
    lim.add_argument("--glissade-json", required=True, metavar="FILE",
                     help="a `glissade-worker solve --json` of the same scene and point, or a `run --json` "
                     "(its glissade histories)")
    for name in ("deck", "run"):
        p = sub.add_parser(name)
        p.add_argument("scene")
        p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
        p.add_argument("--kn", type=float, default=3e15, help="contact penalty, Pa/m (3e15)")
        p.add_argument("--kt", type=float, default=3e13, help="friction stick slope, Pa/m (3e13)")
        p.add_argument("--alpha", type=float, default=-0.05,
                       help="ccx's Hilber-Hughes-Taylor alpha in [-1/3, 0] (-0.05; 0: Newmark average acceleration)")
        p.add_argument("--contact", choices=["penalty", "mortar", "linmortar", "pgmortar", "pglinmortar"],
                       default="penalty", help="penalty: surface-to-surface with slope --kn; the mortar kinds: "
                       "ccx's mortar contact, HARD (Lagrange multipliers)")
        if name == "deck":
            p.add_argument("--dt", type=float, help="largest ccx increment (default: the scene's dt)")
            p.add_argument("-o", "--output", required=True)
            p.add_argument("--summary", action="store_true", help="print the deck's counts as JSON")
        else:
            p.add_argument("--ccx-dt", type=float, help="largest ccx increment (default: the scene's dt)")
            p.add_argument("--glissade-steps", type=int, help="glissade's steps (default: the scene's)")
            p.add_argument("--tol", type=float, default=1e-6)
            p.add_argument("--worker", default="target/release/glissade-worker")
            p.add_argument("--ccx", default="ccx")
            p.add_argument("--workdir", help="keep ccx's files here (default: a temporary directory)")
            p.add_argument("--json", help="write the histories and the comparison here")
            p.add_argument("--ccx-dat", metavar="FILE",
                           help="read ccx's results from this .dat (of this scene's deck) instead of running ccx")
            p.add_argument("--partial", action="store_true",
                           help="where ccx stopped before the end (too many cutbacks), compare up to where it "
                                "stopped (the finals: the values there)")
            p.add_argument("--glissade-json", metavar="FILE",
                           help="read glissade's solve from this `glissade-worker solve --json` output "
                                "instead of running it (its steps must be --glissade-steps)")
    args = ap.parse_args()
    if args.cmd == "kt-limit":
        try:
            runs = [json.load(open(r)) for r in args.runs]
            gl = json.load(open(args.glissade_json))
            kts, lim = kt_limit(runs)
            # a `run --json` carries glissade's histories too
            gq, gsteps = (gl["qoi"], gl["time_steps"]) if "qoi" in gl else (gl["glissade"], gl["glissade_steps"])
        except (OSError, json.JSONDecodeError, KeyError, SceneError) as e:
            print(f"error: kt-limit: {e}", file=sys.stderr)
            return 1
        print(f"ccx at kt {', '.join(f'{k:g}' for k in kts)} Pa/m extrapolated to 1 / kt = 0 (the two stiffest), "
              f"against glissade ({gsteps} steps); 'soft pair': the two softest's extrapolation")
        print(f"{'QoI':<14} {'ccx kt->inf':>12} {'soft pair':>12} {'glissade':>12} {'final diff':>11} {'L2 diff':>9}")
        for name, (times, stiff, soft) in lim.items():
            g = gq[name]
            kept = [(t, v) for t, v in zip(g["times"], g["values"]) if t <= times[-1] * (1 + 1e-9)]
            l2, fin = compare(([t for t, _ in kept], [v for _, v in kept]), (times, stiff))
            print(f"{name:<14} {stiff[-1]:12.4e} {soft[-1]:12.4e} {kept[-1][1]:12.4e} {100 * fin:10.2f}% {100 * l2:8.2f}%")
        return 0
    try:
        text = open(args.scene).read()
        scene = Scene(text, parse_set(args.set))
        mesh = Mesh(scene)
    except KeyError as e:
        print(f"error: {args.scene}: missing key {e} (docs/scenes.md)", file=sys.stderr)
        return 1
    except (SceneError, OSError, tomllib.TOMLDecodeError) as e:
        print(f"error: {args.scene}: {e}", file=sys.stderr)
        return 1
    scene_dt = scene.duration / scene.steps
    title = f"glissade scene {os.path.basename(args.scene)} at " + \
        ", ".join(f"{k}={v:g}" for k, v in sorted(scene.params.items()))
    if args.cmd == "deck":
        dt = args.dt or scene_dt
        with open(args.output, "w") as f:
            f.write(write_deck(scene, mesh, dt, args.kn, args.kt, args.alpha, title, args.contact))
        if args.summary:
            print(json.dumps(dict(nodes=len(mesh.nodes), elements=len(mesh.elements),
                                  qoi_nodes={q["name"]: n for q, n in zip(scene.qois, qoi_nodes(scene, mesh))})))
        return 0

    ccx = shutil.which(args.ccx)
    if ccx is None and not args.ccx_dat:
        print(f"skipped: CalculiX ({args.ccx}) is not installed (Debian: apt-get install calculix-ccx)",
              file=sys.stderr)
        return 3
    if not args.glissade_json and not os.access(args.worker, os.X_OK):
        print(f"error: {args.worker}: no glissade-worker there (cargo build --release -p glissade-worker)",
              file=sys.stderr)
        return 1
    dt = args.ccx_dt or scene_dt
    steps = args.glissade_steps or scene.steps
    work = args.workdir or tempfile.mkdtemp(prefix="glissade-ccx-")
    os.makedirs(work, exist_ok=True)
    with open(os.path.join(work, "deck.inp"), "w") as f:
        f.write(write_deck(scene, mesh, dt, args.kn, args.kt, args.alpha, title, args.contact))

    dat = args.ccx_dat or os.path.join(work, "deck.dat")
    ccx_cpu = ccx_wall = float("nan")
    if not args.ccx_dat:
        # ccx, one thread (the CPU comparison is per job)
        env = dict(os.environ, OMP_NUM_THREADS="1", CCX_NPROC_EQUATION_SOLVER="1")
        c0, w0 = child_cpu(), time.time()
        with open(os.path.join(work, "ccx.log"), "w") as log:
            rc = subprocess.run([ccx, "-i", "deck"], cwd=work, env=env, stdout=log,
                                stderr=subprocess.STDOUT).returncode
        ccx_cpu, ccx_wall = child_cpu() - c0, time.time() - w0
        if rc != 0 and not args.partial:
            print(f"error: ccx exited {rc}; see {work}/ccx.log", file=sys.stderr)
            return 1
    ref = ccx_histories(scene, mesh, read_dat(dat))
    end = ref[scene.qois[0]["name"]][0][-1]
    if abs(end - scene.duration) > 1e-6 * scene.duration:
        if not args.partial:
            print(f"error: ccx stopped at t = {end:.4g}; see {work}/ccx.log (--partial compares up to there)",
                  file=sys.stderr)
            return 1
        print(f"PARTIAL: ccx stopped at t = {end:.4g} s of {scene.duration:.4g}: compared over [0, {end:.4g}]")

    # glissade at its number of steps
    gscene = os.path.join(work, "glissade-scene.toml")
    with open(gscene, "w") as f:
        f.write(with_steps(text, steps))
    cmd = [args.worker, "solve", gscene, "--tol", str(args.tol), "--json"] + \
        [a for s in args.set for a in ("--set", s)]
    if args.glissade_json:
        with open(args.glissade_json) as f:
            gl = json.load(f)
        gl_cpu = gl_wall = float("nan")
        if gl["time_steps"] != steps or not gl["converged"]:
            print(f"error: {args.glissade_json}: {gl['time_steps']} steps, converged {gl['converged']}; "
                  f"expected {steps} steps, converged", file=sys.stderr)
            return 1
    else:
        c0, w0 = child_cpu(), time.time()
        res = subprocess.run(cmd, capture_output=True, text=True)
        gl_cpu, gl_wall = child_cpu() - c0, time.time() - w0
        if res.returncode != 0:
            print(f"error: glissade-worker exited {res.returncode}: {res.stderr.strip()}", file=sys.stderr)
            return 1
        gl = json.loads(res.stdout)

    rows = []
    print(f"{title}: ccx dt {dt:.3g} s ({ccx_cpu:.1f} s CPU), glissade {steps} steps, dt "
          f"{scene.duration / steps:.3g} s, tol {args.tol:g} ({gl_cpu:.1f} s CPU, {gl['iterations']} iterations)")
    print(f"{'QoI':<14} {'ccx final':>12} {'glissade final':>15} {'final diff':>11} {'L2 diff':>9}")
    for q in scene.qois:
        g = gl["qoi"][q["name"]]
        # (up to where ccx stopped, with --partial)
        kept = [(t, v) for t, v in zip(g["times"], g["values"]) if t <= end * (1 + 1e-9)]
        hist = ([t for t, _ in kept], [v for _, v in kept])
        l2, fin = compare(hist, ref[q["name"]])
        rows.append(dict(qoi=q["name"], ccx_final=ref[q["name"]][1][-1], glissade_final=hist[1][-1],
                         final_rel=fin, l2_rel=l2))
        print(f"{q['name']:<14} {ref[q['name']][1][-1]:12.4e} {hist[1][-1]:15.4e} {100 * fin:10.2f}% {100 * l2:8.2f}%")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(scene=args.scene, parameters=scene.params, ccx_dt=dt, ccx_end=end, glissade_steps=steps, tol=args.tol,
                           kn=args.kn, kt=args.kt, ccx_cpu_s=ccx_cpu, ccx_wall_s=ccx_wall, glissade_cpu_s=gl_cpu,
                           glissade_wall_s=gl_wall, glissade_iterations=gl["iterations"], comparison=rows,
                           ccx={k: {"times": v[0], "values": v[1]} for k, v in ref.items()},
                           glissade={k: {"times": v["times"], "values": v["values"]} for k, v in gl["qoi"].items()}),
                      f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
