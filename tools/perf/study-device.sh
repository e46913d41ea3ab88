#!/usr/bin/env bash
# A study through the service on one node: a real coordinator, one pool of RANKS ranks (one
# thread each), the CLI submitting a grid, as a user of deploy/bundle-worker.sh --service would
# run it (docs/performance.md, "The paper-size study"). Stops at the study's end or after SECONDS,
# whichever comes first, and keeps what was solved: the study's JSON (`show --json`, every
# point's work, wall time and warm start), its progress every 10 s, the coordinator's and the
# pool's logs.
#
#   tools/perf/study-device.sh BUNDLE_DIR OUT_DIR SECONDS [RANKS] [SCENE] [GRID...]
#   tools/perf/study-device.sh /tmp/g out 300 16 scenes/three-blocks-paper.toml f1=0.1:0.2:11 f2=0.1:0.2:11
#
# BUNDLE_DIR: an unpacked bundle (bin/ with glissade-server, glissade, glissade-worker, mpiexec;
# lib/). TOL (2e-4) is the study's tolerance; the audits are off (they are measured elsewhere).
set -euo pipefail
g=${1:?usage: study-device.sh BUNDLE_DIR OUT_DIR SECONDS [RANKS] [SCENE] [GRID...]}
out=${2:?usage}
seconds=${3:?usage}
ranks=${4:-16}
scene=${5:-scenes/three-blocks-paper.toml}
shift 5 || shift $#
grid=("$@")
[[ ${#grid[@]} -gt 0 ]] || grid=(f1=0.1:0.2:11 f2=0.1:0.2:11)
export LD_LIBRARY_PATH=$g/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH} PATH=$g/bin:$PATH
mkdir -p "$out"
work=$(mktemp -d)
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
  sleep 2
  pkill -f 'glissade-worker pool' 2>/dev/null || true
  wait 2>/dev/null || true
}
trap cleanup EXIT

glissade-server --data "$work/db" --listen 127.0.0.1:0 > "$work/port" 2> "$out/server.log" &
pids+=($!)
for _ in $(seq 100); do [[ -s "$work/port" ]] && break; sleep 0.1; done
url="http://$(sed 's/listening on //' "$work/port")"
args=(--server "$url" submit "$scene" --tol "${TOL:-2e-4}" --audit 0 --refine 0 --surface-audit 0)
for x in "${grid[@]}"; do args+=(--grid "$x"); done
study=$(glissade "${args[@]}")
start=$(date +%s)
echo "study $study: $scene ${grid[*]} tol ${TOL:-2e-4}, one pool of $ranks ranks, at most $seconds s" | tee "$out/progress.txt"
GLISSADE_SOLVER_THREADS=1 RUST_LOG=glissade_worker::pool=info \
  mpiexec -launcher fork -n "$ranks" glissade-worker pool --coordinator "$url" --pool-id node \
  2> "$out/pool.log" &
pids+=($!)
while :; do
  sleep 10
  elapsed=$(( $(date +%s) - start ))
  glissade --server "$url" show "$study" --points --json > "$work/study.json" || continue
  line=$(python3 - "$work/study.json" "$elapsed" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
points = s["points"]
# (the proto's JSON: enums by name, 64-bit integers as strings, an absent message left out)
done = [p for p in points if p["state"] == "POINT_STATE_DONE"]
warm = [p for p in done if p.get("started_from")]
work = sum(p["work"] for p in done)
secs = sum(p["wall_seconds"] for p in done)
running = sum(int(p["iterations"]) for p in points if p["state"] == "POINT_STATE_LEASED")
state = s["state"].removeprefix("STUDY_STATE_").lower()
print(f"{sys.argv[2]} s: {len(done)} of {len(points)} done ({len(warm)} warm), work {work:.1f}, "
      f"solve wall {secs:.1f} s, {s['progress']['leased']} solving ({running} iterations so far), state {state}")
PY
) || line="$elapsed s: (no progress read)"
  echo "$line" | tee -a "$out/progress.txt"
  [[ $line == *"state done"* ]] && break
  (( elapsed >= seconds )) && break
done
cp "$work/study.json" "$out/study.json"
