#!/usr/bin/env python3
"""The response surface's benchmark (docs/surrogate.md, "Benchmark"): studies run through the
real service, their surfaces judged against a dense reference grid.

Each design runs on a coordinator of its own (a fresh database: no study answers or warm-starts
another's points) with one single-process pool; with --shared all the designs run one after
the other on one coordinator and database (a later one continues or warm-starts from the earlier
ones' points: a tighter target after a looser one). Once the study and its surface audit are done,
the surface that `glissade surface --at` answers is read at every reference point off the design
and compared with the reference's value: per QoI, the largest and mean |error| relative to the
QoI's spread over the box (the study's values and the reference's: the surface audit's measure,
core::study::holdout), and the share within 2 predicted standard deviations; beside them the study's work (dynamic iterations +
static iterations / steps, summed over its points), wall time, and what its own surface audit
estimated.

    python3 tools/surface_bench.py --bin target/release --scene S.toml --reference R.json \
        --out DIR --qoi middle_ux,slip_A,slip_B -- 'NAME|submit arguments' ...

e.g. 'cold 11 x 11|--grid f1=0.1:0.2:11 --grid f2=0.1:0.2:11 --strategy cold'. Only the
standard library: no numpy.
"""

import argparse
import json
import os
import shlex
import subprocess
import sys
import time


def run(cmd, **kw):
    out = subprocess.run(cmd, capture_output=True, text=True, **kw)
    if out.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({out.returncode}):\n{out.stdout}\n{out.stderr}")
    return out.stdout


class Service:
    """A coordinator on a fresh database and one pool; both stopped (by their pid) on exit."""

    def __init__(self, bin_dir, data, log_dir):
        self.bin = bin_dir
        self.server = subprocess.Popen(
            ["nice", "-n", "10", f"{bin_dir}/glissade-server", "--listen", "127.0.0.1:0", "--data", data],
            stdout=subprocess.PIPE, stderr=open(f"{log_dir}/server.log", "w"), text=True)
        line = self.server.stdout.readline()
        if not line.startswith("listening on "):
            self.close()
            sys.exit(f"glissade-server said {line!r}; see {log_dir}/server.log")
        self.url = "http://" + line.split()[-1]
        self.pool = subprocess.Popen(
            ["nice", "-n", "10", f"{bin_dir}/glissade-worker", "pool", "--coordinator", self.url,
             "--pool-id", "bench", "--spool", f"{log_dir}/spool"],
            stdout=subprocess.DEVNULL, stderr=open(f"{log_dir}/pool.log", "w"))

    def cli(self, *args):
        return run([f"{self.bin}/glissade", *args, "--server", self.url])

    def show(self, study, points=False):
        return json.loads(self.cli("show", str(study), "--json", *(["--points"] if points else [])))

    def close(self):
        for p in (getattr(self, "pool", None), self.server):
            if p is not None and p.poll() is None:
                p.terminate()
                try:
                    p.wait(30)
                except subprocess.TimeoutExpired:
                    p.kill()


def finished(study):
    # (`show --json` is GetStudy's study in the proto's JSON: enums by name, 64-bit integers as strings)
    return study["state"] in ("STUDY_STATE_DONE", "STUDY_STATE_CANCELLED", "STUDY_STATE_FAILED")


def start(point):
    """How a point began: answered by a stored solution, continued from a stored solution of the
    same point (at a looser tolerance), warm-started from another point, or cold."""
    if point.get("answered"):
        return "answered"
    source = point.get("started_from")
    if not source:
        return "cold"
    same = all(abs(source["parameters"].get(n, v) - v) <= 1e-12 * max(1.0, abs(v))
               for n, v in point["parameters"].items())
    return "continued" if same else "warm"


def measure(bin_dir, scene, reference, sets, qois, name, args, out, shared=None):
    work_dir = os.path.join(out, name.replace(" ", "_"))
    os.makedirs(work_dir, exist_ok=True)
    service = shared or Service(bin_dir, os.path.join(work_dir, "db"), work_dir)
    try:
        submitted = json.loads(service.cli("submit", scene, *shlex.split(args), "--audit", "0", "--refine", "0",
                                           "--json"))
        sid = submitted["study_id"]
        while not finished(study := service.show(sid)):
            time.sleep(1)
        # then its surface audit (held-out points solved after the study)
        audit = study.get("surface_accuracy")
        while audit and not finished(service.show(audit["audit_study_id"])):
            time.sleep(1)
        study = service.show(sid, points=True)
        points = [p for p in study["points"] if p["state"] == "POINT_STATE_DONE"]
        params = study["parameters"]
        design = [tuple(p["parameters"][n] for n in params) for p in points]
        # reference points off the design (at a design point the surface interpolates its value)
        off = [r for r in reference
               if not any(all(abs(r["point"][n] - d[k]) < 1e-9 * max(1.0, abs(d[k])) for k, n in enumerate(params))
                          for d in design)]
        at = [",".join(f"{n}={r['point'][n]!r}" for n in params) for r in off]
        ats = [a for x in at for a in ("--at", x)]
        predicted = json.loads(service.cli("surface", str(sid), "--json", *ats))["points"] if at else []
    finally:
        if shared is None:
            service.close()
    row = {
        "name": name, "args": args, "study": sid, "points": len(points),
        "work": sum(p["work"] or 0.0 for p in points),
        # how each point began: a later design on a shared service continues or warm-starts
        # from the earlier ones' points
        "starts": {k: sum(start(p) == k for p in points) for k in ("answered", "continued", "warm", "cold")},
        "wall_s": (int(study["finished_unix_ms"]) - int(study["created_unix_ms"])) / 1e3,
        "tolerance": study["tolerance"], "target": study.get("target"),
        "audit": study.get("surface_accuracy"), "judged_on": len(off), "qoi": {},
        # every number the errors come from, to judge again on another measure
        "design": [p["parameters"] for p in points],
        "design_values": {q: [p["qoi"].get(q) for p in points] for q in qois},
        "predicted": [{"at": r["point"], "reference": r["qoi"], "set": r["set"], "qoi": p["qoi"]}
                      for r, p in zip(off, predicted)],
    }
    for name_set in sets:
        row["qoi"][name_set] = judge(row, qois, name_set)
    return row


def judge(row, qois, name_set):
    """Per QoI over the reference points of one set: largest and mean |error| relative to the
    QoI's spread over the box (the study's values and the set's: the surface audit's measure),
    and the share within 2 predicted standard deviations."""
    judged = {}
    pairs = [p for p in row["predicted"] if p["set"] == name_set]
    for q in qois:
        values = [p["reference"][q] for p in pairs] + [v for v in row["design_values"][q] if v is not None]
        spread = max(values) - min(values)
        errors = [abs(p["qoi"][q]["mean"] - p["reference"][q]) for p in pairs]
        within = sum(e <= 2 * p["qoi"][q]["std"] for e, p in zip(errors, pairs))
        judged[q] = {"largest": max(errors) / spread, "mean": sum(errors) / len(errors) / spread,
                     "within_2sd": within / len(pairs), "count": len(pairs)}
    return judged


def table(rows, qois, name_set):
    lines = [f"judged at the reference points of {name_set}",
             "| design | points | work | wall (s) | QoI | largest / mean (truth) | within 2 sd | audit: largest / mean (mean / truth's) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for k, q in enumerate(qois):
            t = r["qoi"][name_set][q]
            a = ((r["audit"] or {}).get("qoi") or {}).get(q)
            audit = (f"{a['largest']:.3f} / {a['mean']:.4f} ({a['mean'] / t['mean']:.2f})" if a else "-")
            head = (f"| {r['name']} | {r['points']} | {r['work']:.0f} | {r['wall_s']:.0f} |" if k == 0
                    else "| | | | |")
            lines.append(f"{head} {q} | {t['largest']:.3f} / {t['mean']:.4f} | {100 * t['within_2sd']:.0f} % | {audit} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", default="target/release")
    ap.add_argument("--scene", required=True)
    ap.add_argument("--reference", default=[], action="append",
                    help="results.json of `glissade-worker study` (repeatable: each set judged apart)")
    ap.add_argument("--shared", action="store_true",
                    help="run the designs one after the other on one coordinator and database (a later "
                         "design continues or warm-starts from the earlier ones' points)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--qoi", default="middle_ux,slip_A,slip_B")
    ap.add_argument("designs", nargs="+", help="'NAME|submit arguments'")
    a = ap.parse_args()
    qois = a.qoi.split(",")
    reference = [dict(r, set=path) for path in a.reference for r in json.load(open(path))["records"]]
    os.makedirs(a.out, exist_ok=True)
    rows = []
    shared = Service(os.path.abspath(a.bin), os.path.join(a.out, "db"), a.out) if a.shared else None
    try:
        for d in a.designs:
            name, args = d.split("|", 1)
            started = time.time()
            rows.append(measure(os.path.abspath(a.bin), a.scene, reference, a.reference, qois, name, args, a.out,
                                shared))
            print(f"{name}: {time.time() - started:.0f} s, {rows[-1]['points']} points, work {rows[-1]['work']:.0f}, "
                  f"starts {rows[-1]['starts']}", file=sys.stderr)
            json.dump(rows, open(os.path.join(a.out, "bench.json"), "w"), indent=1)
    finally:
        if shared is not None:
            shared.close()
    for name_set in a.reference:
        print(table(rows, qois, name_set))


if __name__ == "__main__":
    main()
