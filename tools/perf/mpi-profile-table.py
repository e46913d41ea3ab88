#!/usr/bin/env python3
"""The scaling table of docs/performance.md, "Where a rank's time goes", from the JSON files of
tools/perf/mpi-profile-device.sh (OUT_DIR/runs.jsonl: `solve --profile --json`, a line a run).

    python3 tools/perf/mpi-profile-table.py OUT_DIR

Time per dynamic iteration as deploy/bench-mpi-scaling.sh counts it (linear + local stages, a
static iteration one step of the interval); the split is the profile's, summed over the whole
solve (model build and factorisation included, in compute), for the slowest rank and as the
mean of the ranks; the per-step collective is the largest sum called once a time step.
"""
import json
import pathlib
import re
import sys


def main(out: str) -> None:
    rows = []
    for line in (pathlib.Path(out) / "runs.jsonl").read_text().splitlines():
        d = json.loads(line)
        m = re.search(r"-p(\d+)-t(\d+)$", d["run"])
        p, threads = int(m.group(1)), int(m.group(2))
        t = d["timings"]
        static_it = d["static_stage"]["iterations"] if d["static_stage"] else 0
        dyn_it = d["iterations"] - static_it
        steps = d["time_steps"]
        per_it = (t["linear_stage"] + t["local_stage"]) / (dyn_it * steps + static_it) * steps
        prof = d.get("profile")
        rows.append((p, threads, per_it, t, prof, d))
    if not rows:
        sys.exit(f"no runs in {out}")
    base = {th: it * p for p, th, it, *_ in rows if p == 1}
    ref = base.get(1) or next(iter(base.values()), None)
    d0 = rows[0][5]
    print(f"{d0['dofs']} dofs, {d0['substructures']} substructures, {d0['time_steps']} steps")
    print("| ranks | threads a rank | s / dynamic iteration | speed-up | efficiency | wall s | compute (slowest, mean) s "
          "| wait (largest) s | transfer s | exchange (largest) s | imbalance | jitter s | per-step sum: calls, wait / call / rank ms |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for p, th, it, t, prof, d in sorted(rows, key=lambda r: (r[1], r[0])):
        speed = ref / it if ref else float("nan")
        cells = [str(p), str(th), f"{it:.3f}", f"{speed:.2f}", f"{100 * speed / p:.0f} %"]
        if prof:
            ranks = prof["ranks"]
            comp = [r["compute"] for r in ranks]
            step = [g for g in prof["collectives"] if g["kind"] == "sum" and g["calls"] >= steps]
            step = max(step, key=lambda g: g["len"]) if step else None
            per_call = f"{step['calls']}, {1e3 * step['wait'] / step['calls'] / p:.2f}" if step else "-"
            cells += [f"{max(r['wall'] for r in ranks):.1f}", f"{max(comp):.1f}, {sum(comp) / p:.1f}",
                      f"{max(r['wait'] for r in ranks):.2f}", f"{ranks[0]['transfer']:.3f}",
                      f"{max(r['exchange'] for r in ranks):.2f}", f"{prof['imbalance']:.2f}",
                      f"{prof['jitter']:.2f}", per_call]
        else:
            cells += ["-"] * 8
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "out")
