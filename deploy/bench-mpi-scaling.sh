#!/usr/bin/env bash
# Strong scaling of one solve over MPI ranks: the same scene, a fixed number of iterations per
# stage (tolerance unreachable in that many), P ranks for each P given. Prints time per dynamic iteration,
# speed-up, parallel efficiency and the shares of the macro problem and of communication.
#
#   deploy/bench-mpi-scaling.sh SCENE.toml "1 2" [ITERATIONS] [single|multi] [WORKER_BINARY]
#
# On a node without MPICH, use the bundle of deploy/bundle-worker.sh (its mpiexec, with
# MPIEXEC_FLAGS="-launcher fork").
set -euo pipefail
scene=${1:?usage: bench-mpi-scaling.sh SCENE.toml "1 2 4" [ITERATIONS] [single|multi] [WORKER]}
ranks=${2:-"1 2"}
iterations=${3:-10}
scale=${4:-multi}
worker=${5:-target/release/glissade-worker}
[[ -x "$worker" ]] || { echo "no worker binary at $worker (cargo build --release -p glissade-worker)" >&2; exit 1; }
results=$(mktemp -d)
trap 'rm -rf "$results"' EXIT
for p in $ranks; do
  # exit 2 means "not converged": expected, the tolerance is unreachable on purpose
  ${MPIEXEC:-mpiexec.mpich} ${MPIEXEC_FLAGS:-} -n "$p" "$worker" solve "$scene" --scale "$scale" --tol 1e-10 \
    --max-iter "$iterations" --json > "$results/$p.json" || [[ $? -eq 2 ]]
done
python3 - "$results" "$scene" "$iterations" "$scale" $ranks <<'PY'
import json, sys
results, scene, iterations, scale, ranks = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4], sys.argv[5:]
rows = []
for p in ranks:
    d = json.load(open(f"{results}/{p}.json"))
    t = d["timings"]
    static_it = d["static_stage"]["iterations"] if d["static_stage"] else 0
    dyn_it = d["iterations"] - static_it
    steps = d["time_steps"]
    # a static iteration is one step, a dynamic one `steps` steps
    per_iteration = (t["linear_stage"] + t["local_stage"]) / (dyn_it * steps + static_it) * steps
    rows.append((int(p), per_iteration, t["macro_problem"] / (t["linear_stage"] + t["local_stage"]),
                 t["communication"] / (t["linear_stage"] + t["local_stage"]), t["factorisation"], d["dofs"], d["substructures"]))
base = rows[0][1] * rows[0][0]
print(f"{scene}: {rows[0][5]} dofs, {rows[0][6]} substructures, {scale}-scale, {iterations} iterations per stage")
print("| ranks | s / dynamic iteration | speed-up | efficiency | macro share | communication share | factorisation s |")
print("|---|---|---|---|---|---|---|")
for p, it, mac, com, fac, _, _ in rows:
    print(f"| {p} | {it:.3f} | {base / it:.2f} | {100 * base / it / p:.0f} % | {100 * mac:.1f} % | {100 * com:.1f} % | {fac:.2f} |")
PY
