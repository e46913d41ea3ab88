#!/usr/bin/env python3
"""Newmark gamma study for glissade contact scenes.

Runs the release glissade-worker (GLISSADE_WORKER, default target/release/glissade-worker) one
solve at a time under `nice -n 5 timeout 300`, and writes OUT/results.json and OUT/tables.md
(OUT: GAMMA_OUT, default /tmp/gamma). The measurement behind solve --accuracy's Newmark gamma for
contact scenes (docs/accuracy.md, "The time scheme").

Usage: python3 tools/perf/newmark_gamma/run.py [--only bar-impact,sliding-block,chatter-block,smooth-bar,extras]
"""
import json
import math
import os
import re
import subprocess
import sys
import time

HERE = os.environ.get("GAMMA_OUT", "/tmp/gamma")
REPO = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", ".."))
GW = os.environ.get("GLISSADE_WORKER", os.path.join(REPO, "target", "release", "glissade-worker"))
INPUTS = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "scenes")
RESULTS = os.path.join(HERE, "results.json")
TABLES = os.path.join(HERE, "tables.md")
GAMMAS = [0.5, 0.505, 0.52, 0.55, 0.6]
TOL = "2e-4"
TIMEOUT = 300
SKIP_AFTER = 120.0  # skip finer steps once a coarser sibling took longer than this

# ---------------------------------------------------------------- exact answers
# bar-impact-1d: L = 0.1, E 200e9, rho 7800, initial velocity +v0 towards the wall at x+.
BAR_L, BAR_E, BAR_RHO, V0 = 0.1, 200e9, 7800.0, 1.0
BAR_C = math.sqrt(BAR_E / BAR_RHO)
BAR_F = -BAR_RHO * BAR_C * V0          # wall force during contact (the code's sign: negative)
BAR_TC = 2 * BAR_L / BAR_C              # contact duration
BAR_EXACT_FINAL = {"wall_force": 0.0, "tip_velocity": -V0, "free_end_velocity": -V0}
BAR_SCALE = {"wall_force": abs(BAR_F), "tip_velocity": V0, "free_end_velocity": V0}

# chattering block: rigid block's closed form
CB_M = 7850 * 0.024 * 0.012
CB_N = 8e6 * 0.024
CB_RATE = 1e7 * 0.012 / 4e-4
CB_T = 4e-4
CB_TSTAR = 0.4 * CB_N / CB_RATE
CB_RIGID = CB_RATE * (CB_T - CB_TSTAR) ** 3 / (6 * CB_M)


def sb_rigid(f=0.3, push=12e6):
    """sliding-block-2d's rigid closed form (for reference only; the block is elastic and the
    pressure is applied at once, so this is not the exact answer)."""
    m = 7800 * 0.02 * 0.01
    n = 1e7 * 0.02
    rate = push * 0.01 / 1e-4
    t = 1e-4
    ts = f * n / rate
    return rate * max(t - ts, 0.0) ** 3 / (6 * m)


# ---------------------------------------------------------------- running
def make_scene(src_text, name, steps, gamma):
    txt, n = re.subn(r"(?m)^steps\s*=\s*\d+\s*$",
                     f"steps = {steps}\nnewmark_gamma = {gamma}", src_text, count=1)
    assert n == 1, name
    os.makedirs(SCENES, exist_ok=True)
    path = os.path.join(SCENES, f"{name}_s{steps}_g{gamma}.toml")
    with open(path, "w") as fh:
        fh.write(txt)
    return path


def solve(path, extra=(), tol=TOL):
    cmd = ["nice", "-n", "5", "timeout", str(TIMEOUT), GW, "solve", path,
           "--tol", tol, "--json", *extra]
    t0 = time.time()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.time() - t0
    rec = {"cmd": " ".join(cmd), "rc": p.returncode, "elapsed": wall}
    if p.returncode in (124, 137):
        rec["status"] = "timeout"
        return rec
    try:
        d = json.loads(p.stdout)
    except Exception:
        rec["status"] = "error"
        rec["stderr"] = p.stderr[-2000:]
        return rec
    rec["status"] = "ok"
    for k in ("converged", "iterations", "dynamic_sweeps", "wall_seconds", "error_indicator",
              "contact", "dynamic_diagnosis", "dynamic_windows", "dynamic_windows_stalled"):
        rec[k] = d.get(k)
    rec["qoi"] = d.get("qoi", {})
    return rec


def ladder(results, key, src_text, base_steps, mults, post, extra=(), tol=TOL):
    out = results.setdefault(key, {})
    for g in GAMMAS:
        row = out.setdefault(str(g), {})
        slow = False
        for m in mults:
            steps = int(round(base_steps * m))
            if slow:
                row[str(m)] = {"status": "skipped", "steps": steps,
                               "why": f"coarser sibling took > {SKIP_AFTER:.0f} s"}
                continue
            path = make_scene(src_text, key, steps, g)
            rec = solve(path, extra, tol)
            rec["steps"] = steps
            if rec["status"] == "ok":
                post(rec, steps)
            # keep the histories out of results.json except what we need
            rec.pop("qoi", None)
            row[str(m)] = rec
            print(f"{key} gamma={g} x{m} ({steps} steps): {rec['status']} "
                  f"conv={rec.get('converged')} it={rec.get('iterations')} "
                  f"t={rec['elapsed']:.1f}s {rec.get('errors', '')}", flush=True)
            if rec["elapsed"] > SKIP_AFTER or rec["status"] == "timeout":
                slow = True
            save(results)


def save(results):
    with open(RESULTS, "w") as fh:
        json.dump(results, fh, indent=1)


# ---------------------------------------------------------------- post-processing
def post_bar_impact(rec, steps):
    q = rec["qoi"]
    errs, finals = {}, {}
    for name in ("tip_velocity", "free_end_velocity", "wall_force"):
        v = q[name]["final"]
        finals[name] = v
        errs[name] = (v - BAR_EXACT_FINAL[name]) / BAR_SCALE[name]
    # L2 error of the wall force history against the exact pulse (samples t > 0, uniform dt)
    t = q["wall_force"]["times"]
    f = q["wall_force"]["values"]
    num = den = 0.0
    for ti, fi in zip(t[1:], f[1:]):
        ex = BAR_F if ti < BAR_TC else 0.0
        num += (fi - ex) ** 2
        den += ex ** 2
    errs["wall_force_L2"] = math.sqrt(num / den)
    rec["finals"] = finals
    rec["errors"] = errs


def post_slip(name, exact):
    def post(rec, steps):
        v = rec["qoi"][name]["final"]
        rec["finals"] = {k: rec["qoi"][k]["final"] for k in rec["qoi"]}
        rec["errors"] = {name: (v - exact) / exact}
        # peak-to-peak of the normal force relative to its mean over the last half, if present
    return post


def post_smooth(ref):
    def post(rec, steps):
        v = rec["qoi"]["tip_ux"]["final"]
        rec["finals"] = {"tip_ux": v}
        rec["errors"] = {"tip_ux": (v - ref) / abs(ref)}
    return post


# ---------------------------------------------------------------- tables
def fmt_cell(rec, err_key):
    st = rec.get("status")
    if st == "skipped":
        return "skipped"
    if st == "timeout":
        return "timeout (300 s)"
    if st != "ok":
        return "error"
    conv = "yes" if rec.get("converged") else "**no**"
    e = rec.get("errors", {}).get(err_key)
    es = "n/a" if e is None else f"{100 * e:+.3g} %"
    return f"{rec['iterations']} / {conv} / {es}"


def table(results, key, mults, err_keys, title, note=""):
    if key not in results:
        return ""
    lines = [f"### {title}", ""]
    if note:
        lines += [note, ""]
    for ek in err_keys:
        lines.append(f"**{ek}** (cells: iterations / converged? / error)")
        lines.append("")
        lines.append("| gamma | " + " | ".join(f"x{m} ({results[key][str(GAMMAS[0])][str(m)]['steps']} steps)" for m in mults) + " |")
        lines.append("|---|" + "---|" * len(mults))
        for g in GAMMAS:
            row = results[key].get(str(g), {})
            cells = [fmt_cell(row[str(m)], ek) if str(m) in row else "" for m in mults]
            lines.append(f"| {g} | " + " | ".join(cells) + " |")
        lines.append("")
    # wall time / sweeps line
    lines.append("wall seconds (dynamic sweeps):")
    lines.append("")
    lines.append("| gamma | " + " | ".join(f"x{m}" for m in mults) + " |")
    lines.append("|---|" + "---|" * len(mults))
    for g in GAMMAS:
        row = results[key].get(str(g), {})
        cells = []
        for m in mults:
            r = row.get(str(m), {})
            if r.get("status") == "ok":
                cells.append(f"{r['wall_seconds']:.2f} ({r['dynamic_sweeps']:.0f})")
            else:
                cells.append(r.get("status", ""))
        lines.append(f"| {g} | " + " | ".join(cells) + " |")
    lines.append("")
    return "\n".join(lines)


def write_tables(results):
    parts = ["# Newmark gamma study (glissade-worker, --tol 2e-4)", ""]
    parts.append(table(results, "bar-impact-1d", BAR_MULTS,
                       ["tip_velocity", "free_end_velocity", "wall_force", "wall_force_L2"],
                       "bar-impact-1d (base 400 steps)",
                       f"Exact: wall force {BAR_F:.4g} Pa for {BAR_TC * 1e6:.3f} us, then 0; final "
                       "velocities -v0 = -1 m/s. Velocity errors relative to v0, wall_force final "
                       "relative to rho c v0, wall_force_L2 = ||F - F_exact||_2 / ||F_exact||_2 over "
                       "the history."))
    for key, title in (("sliding-block-2d", "sliding-block-2d, defaults (f 0.3, push 12 MPa; base 100 steps)"),
                       ("sliding-block-2d-f0.4-push2e7", "sliding-block-2d, --set f=0.4 --set push=2e7 (base 100 steps)")):
        if key in results:
            ex = results[key + "#rigid"]
            parts.append(table(results, key, SB_MULTS, ["slip_centre"], title,
                               f"error against the rigid block's closed form {ex:.5g} m "
                               "(not exact: elastic block, pressure applied at once)."))
    parts.append(table(results, "chatter-block", CB_MULTS, ["slip"],
                       "chattering block (block.toml, base 200 steps)",
                       f"error against the rigid closed form {CB_RIGID:.5g} m"))
    if "smooth-bar#ref" in results:
        ref = results["smooth-bar#ref"]
        parts.append(table(results, "smooth-bar", SMOOTH_MULTS, ["tip_ux"],
                           "smooth clamped Al bar (bar.toml, base 20 steps)",
                           f"error against trapezoidal 1280 steps --tol 1e-8: tip_ux = {ref['value']:.10g} m "
                           f"(converged {ref.get('converged')}, {ref.get('iterations')} iterations); "
                           f"check of the reference (trapezoidal, --tol 1e-8): {results.get('smooth-bar#ref-check')}"))
        parts.append(smooth_orders(results, "smooth-bar"))
        parts.append(table(results, "smooth-bar-tight", SMOOTH_MULTS, ["tip_ux"],
                           "smooth clamped Al bar, same ladder with --tol 1e-8 (time error alone)",
                           "same reference"))
        parts.append(smooth_orders(results, "smooth-bar-tight"))
    parts.append(contact_diag(results))
    parts.append(extras_tables(results))
    with open(TABLES, "w") as fh:
        fh.write("\n".join(p for p in parts if p))


def smooth_orders(results, key):
    if key not in results:
        return ""
    lines = [f"{key}: observed order log2(e(dt)/e(dt/2)) for tip_ux:", "",
             "| gamma | " + " | ".join(f"x{a}->x{b}" for a, b in zip(SMOOTH_MULTS, SMOOTH_MULTS[1:])) + " |",
             "|---|" + "---|" * (len(SMOOTH_MULTS) - 1)]
    for g in GAMMAS:
        row = results[key].get(str(g), {})
        cells = []
        for a, b in zip(SMOOTH_MULTS, SMOOTH_MULTS[1:]):
            try:
                ea = abs(row[str(a)]["errors"]["tip_ux"])
                eb = abs(row[str(b)]["errors"]["tip_ux"])
                cells.append(f"{math.log2(ea / eb):.2f}")
            except Exception:
                cells.append("")
        lines.append(f"| {g} | " + " | ".join(cells) + " |")
    lines.append("")
    return "\n".join(lines)


def extras_tables(results):
    ex = results.get("extras")
    if not ex:
        return ""
    lines = []
    if "smooth_bar_ext" in ex:
        e = ex["smooth_bar_ext"]
        ns = ["320", "640", "1280", "2560"]
        lines += ["### extra: smooth bar continued (--tol 1e-8; error against Richardson of trapezoidal 2560/5120 "
                  f"= {e['reference']:.10g} m)", "",
                  "| gamma | " + " | ".join(f"{n} steps" for n in ns) + " | order 1280->2560 |",
                  "|---|" + "---|" * (len(ns) + 1)]
        for g, row in e["rel_errors"].items():
            cells = [("%+.3g %%" % (100 * row[n])) if row.get(n) is not None else "" for n in ns]
            try:
                o = "%.2f" % math.log2(abs(row["1280"] / row["2560"]))
            except Exception:
                o = ""
            lines.append(f"| {g} | " + " | ".join(cells) + f" | {o} |")
        lines.append("")
    if "bar_impact_h4" in ex:
        lines += ["### extra: bar-impact-1d with 400 elements (h / 4)", "",
                  "| gamma, steps | iterations / converged | tip_velocity | free_end_velocity | wall_force_L2 |",
                  "|---|---|---|---|---|"]
        for g, row in ex["bar_impact_h4"].items():
            for n, r in row.items():
                if r.get("status") != "ok":
                    lines.append(f"| {g}, {n} | {r.get('status')} | | | |")
                    continue
                e = r["errors"]
                lines.append(f"| {g}, {n} | {r['iterations']} / {'yes' if r['converged'] else '**no**'} | "
                             f"{100 * e['tip_velocity']:+.3g} % | {100 * e['free_end_velocity']:+.3g} % | "
                             f"{100 * e['wall_force_L2']:.3g} % |")
        lines.append("")
    return "\n".join(lines)


def contact_diag(results):
    lines = ["### contact diagnostics (landings_while_sliding / peak_normal_force_ratio)", ""]
    for key, mults in (("sliding-block-2d", SB_MULTS), ("sliding-block-2d-f0.4-push2e7", SB_MULTS),
                       ("chatter-block", CB_MULTS)):
        if key not in results:
            continue
        lines.append(f"**{key}**")
        lines.append("")
        lines.append("| gamma | " + " | ".join(f"x{m}" for m in mults) + " |")
        lines.append("|---|" + "---|" * len(mults))
        for g in GAMMAS:
            row = results[key].get(str(g), {})
            cells = []
            for m in mults:
                r = row.get(str(m), {})
                c = (r.get("contact") or [{}])[0] if r.get("status") == "ok" else {}
                if c:
                    cells.append(f"{c.get('landings_while_sliding')} / {c.get('peak_normal_force_ratio', 0):.2f}")
                else:
                    cells.append(r.get("status", ""))
            lines.append(f"| {g} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


BAR_MULTS = [1, 2, 4, 10]
SB_MULTS = [1, 2, 4, 8]
CB_MULTS = [1, 2, 4, 8]
SMOOTH_MULTS = [1, 2, 4, 8, 16]


def main():
    only = None
    if "--only" in sys.argv:
        only = set(sys.argv[sys.argv.index("--only") + 1].split(","))
    results = {}
    if os.path.exists(RESULTS):
        with open(RESULTS) as fh:
            results = json.load(fh)
    results["meta"] = {"gw": GW, "tol": TOL, "gammas": GAMMAS, "timeout_s": TIMEOUT,
                       "bar_exact": {"c": BAR_C, "force": BAR_F, "contact_duration": BAR_TC},
                       "chatter_block_rigid": CB_RIGID}

    def want(k):
        return only is None or k in only

    if want("bar-impact"):
        src = open(os.path.join(REPO, "scenes", "bar-impact-1d.toml")).read()
        results.pop("bar-impact-1d", None)
        ladder(results, "bar-impact-1d", src, 400, BAR_MULTS, post_bar_impact)
    if want("sliding-block"):
        src = open(os.path.join(REPO, "scenes", "sliding-block-2d.toml")).read()
        results.pop("sliding-block-2d", None)
        results["sliding-block-2d#rigid"] = sb_rigid()
        ladder(results, "sliding-block-2d", src, 100, SB_MULTS,
               post_slip("slip_centre", sb_rigid()))
        key = "sliding-block-2d-f0.4-push2e7"
        results.pop(key, None)
        results[key + "#rigid"] = sb_rigid(0.4, 2e7)
        ladder(results, key, src, 100, SB_MULTS, post_slip("slip_centre", sb_rigid(0.4, 2e7)),
               extra=("--set", "f=0.4", "--set", "push=2e7"))
    if want("chatter-block"):
        src = open(os.path.join(INPUTS, "block.toml")).read()
        results.pop("chatter-block", None)
        ladder(results, "chatter-block", src, 200, CB_MULTS, post_slip("slip", CB_RIGID))
    if want("smooth-bar"):
        src = open(os.path.join(INPUTS, "bar.toml")).read()
        path = make_scene(src, "smooth-bar-ref", 1280, 0.5)
        ref = solve(path, tol="1e-8")
        assert ref["status"] == "ok", ref
        results["smooth-bar#ref"] = {"value": ref["qoi"]["tip_ux"]["final"],
                                     "converged": ref["converged"],
                                     "iterations": ref["iterations"], "cmd": ref["cmd"]}
        print("smooth-bar reference", results["smooth-bar#ref"], flush=True)
        # how good is the 1280-step reference? trapezoidal 640 / 2560 / 5120 at --tol 1e-8
        chk = {}
        for n in (640, 2560, 5120):
            r = solve(make_scene(src, "smooth-bar-ref", n, 0.5), tol="1e-8")
            chk[str(n)] = r["qoi"]["tip_ux"]["final"] if r["status"] == "ok" else r["status"]
        chk["1280"] = results["smooth-bar#ref"]["value"]
        if all(isinstance(chk[k], float) for k in ("2560", "5120")):
            chk["richardson_2560_5120"] = chk["5120"] + (chk["5120"] - chk["2560"]) / 3
            chk["ref_rel_error"] = (chk["1280"] - chk["richardson_2560_5120"]) / abs(chk["richardson_2560_5120"])
        results["smooth-bar#ref-check"] = chk
        results.pop("smooth-bar", None)
        ladder(results, "smooth-bar", src, 20, SMOOTH_MULTS,
               post_smooth(results["smooth-bar#ref"]["value"]))
        # the same ladder with --tol 1e-8, to separate the time error from the iteration error
        results.pop("smooth-bar-tight", None)
        ladder(results, "smooth-bar-tight", src, 20, SMOOTH_MULTS,
               post_smooth(results["smooth-bar#ref"]["value"]), tol="1e-8")
    if want("extras"):
        extras(results)
    save(results)
    write_tables(results)
    print(open(TABLES).read())


def extras(results):
    """Supplements: (a) the smooth bar's ladder continued to 640..2560 steps at --tol 1e-8 against
    the Richardson value of trapezoidal 2560/5120, where the trapezoidal rule is asymptotic;
    (b) bar-impact-1d on a 4x finer mesh (400 elements), to tell the mesh error from the time error."""
    ex = results["extras"] = {}
    chk = results.get("smooth-bar#ref-check", {})
    ref = chk.get("richardson_2560_5120")
    src = open(os.path.join(INPUTS, "bar.toml")).read()
    if ref is not None:
        rows = {}
        for g in GAMMAS:
            for n in (320, 640, 1280, 2560):
                r = solve(make_scene(src, "smooth-bar-ext", n, g), tol="1e-8")
                v = r["qoi"]["tip_ux"]["final"] if r["status"] == "ok" else None
                rows.setdefault(str(g), {})[str(n)] = None if v is None else (v - ref) / abs(ref)
                print("smooth-bar-ext", g, n, rows[str(g)][str(n)], flush=True)
        ex["smooth_bar_ext"] = {"reference": ref, "rel_errors": rows}
    src = open(os.path.join(REPO, "scenes", "bar-impact-1d.toml")).read().replace("elements = [100]", "elements = [400]")
    rows = {}
    for g in (0.5, 0.55, 0.6):
        for n in (1600, 4000):
            path = make_scene(src, "bar-impact-fine-mesh", n, g)
            r = solve(path)
            if r["status"] == "ok":
                post_bar_impact(r, n)
                r.pop("qoi", None)
            rows.setdefault(str(g), {})[str(n)] = r
            print("bar-impact h/4", g, n, r.get("converged"), r.get("iterations"),
                  r.get("errors"), f"{r['elapsed']:.1f}s", flush=True)
    ex["bar_impact_h4"] = rows
    save(results)


if __name__ == "__main__":
    main()
