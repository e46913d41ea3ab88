#!/usr/bin/env bash
# The service's costs (docs/performance.md, section Service), on release builds:
#  1. coordinator overhead per design point with the real solver: one pool solves a grid of
#     SCENE (default three-blocks-small); from the pool's log, the time to lease a point with its
#     warm start and the time to deliver the solution, against the solve time;
#  2. database size per stored solution (solution file, zstd as stored, sled directory growth);
#  3. dispatch throughput with a FAKE, INSTANT solver (tests/src/bin/service-bench.rs): POOLS
#     fake pools complete thousands of points of the tiny scene at once, for each ORDER.
#
#   deploy/bench-service.sh [SCENE] [GRID...]
#   deploy/bench-service.sh scenes/three-blocks-small.toml f1=0.1:0.2:3 f2=0.1:0.2:3
set -euo pipefail
cd "$(dirname "$0")/.."
scene=${1:-scenes/three-blocks-small.toml}
shift || true
grid=("$@")
[[ ${#grid[@]} -gt 0 ]] || grid=(f1=0.1:0.2:3 f2=0.1:0.2:3)
tol=${TOL:-2e-4}
pools=${POOLS:-4}
fake_grid=(${FAKE_GRID:-f1=0.1:0.2:50 f2=0.1:0.2:40})

cargo build --release -p glissade-server -p glissade-worker -p glissade
cargo build --release -p glissade-e2e --bin service-bench
bin=target/release
work=$(mktemp -d)
pids=()
cleanup() { for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done; wait; rm -rf "$work"; }
trap cleanup EXIT

start_server() { # DATA LOG -> sets url
  local port_file="$1.port"
  "$bin/glissade-server" --data "$1" --listen 127.0.0.1:0 > "$port_file" 2> "$2" &
  pids+=($!)
  for _ in $(seq 100); do [[ -s "$port_file" ]] && break; sleep 0.1; done
  url="http://$(sed 's/listening on //' "$port_file")"
}

# 1 and 2: the real solver, one pool. Submitted before the pool starts, so that no lease waits.
start_server "$work/db" "$work/server.log"
args=(--server "$url" submit "$scene" --tol "$tol")
for g in "${grid[@]}"; do args+=(--grid "$g"); done
study=$("$bin/glissade" "${args[@]}")
RUST_LOG=glissade_worker::pool=info "$bin/glissade-worker" pool --coordinator "$url" --pool-id bench 2> "$work/pool.log" &
pids+=($!)
echo "study $study of $scene (${grid[*]}, tol $tol): solving with one pool..." >&2
until "$bin/glissade" --server "$url" show "$study" --json | grep -q '"state":"STUDY_STATE_DONE"'; do
  sleep 1
done
python3 - "$work/pool.log" "$work/server.log" "$work/db" <<'PY'
import os, re, sys
pool, server, db = (open(sys.argv[1]).read(), open(sys.argv[2]).read(), sys.argv[3])
def field(line, name):
    m = re.search(rf"\b{name}=([0-9.e+-]+)", line)
    return float(m.group(1)) if m else None
lines = pool.splitlines()
lease = [(field(l, "lease_ms"), field(l, "init_bytes")) for l in lines if "lease_ms=" in l]
solved = [(field(l, "seconds"), field(l, "gap_ms")) for l in lines if "gap_ms=" in l]
deliver = [field(l, "deliver_ms") for l in lines if "delivered" in l and "deliver_ms=" in l]
completed = [(field(l, "file_bytes"), field(l, "iterations"), field(l, "stored_bytes")) for l in server.splitlines() if "completed" in l and "file_bytes=" in l]
n = len(solved)
print(f"points: {n}")
print("point  lease+warm start (ms)  init MB  gap before solve (ms)  solve (s)  gap/solve %  deliver+store (ms)  iterations")
gaps = solves = 0
for i in range(n):
    (seconds, gap) = solved[i]
    gaps += gap; solves += seconds * 1e3
    print(f"{i:5d}  {lease[i][0]:21.1f}  {lease[i][1]/1e6:7.2f}  {gap:21.1f}  {seconds:9.2f}  {100*gap/(seconds*1e3):11.3f}  {deliver[i]:18.1f}  {int(completed[i][1])}")
# the gap before a solve holds the previous point's delivery; the last delivery follows no solve
last = deliver[-1] if deliver else 0
print(f"total: {gaps + last:.0f} ms outside solves (gaps + last delivery) over {solves/1e3:.1f} s of solves = {100*(gaps + last)/solves:.3f} %")
size = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(db) for f in fs)
fb = sum(c[0] for c in completed) / n; sb = sum(c[2] for c in completed) / n
print(f"solution file {fb/1e6:.3f} MB, stored zstd {sb/1e6:.3f} MB ({100*sb/fb:.0f} %), "
      f"database directory {size/1e6:.2f} MB for {n} solutions = {size/n/1e6:.3f} MB per solution")
PY

# 3: dispatch throughput, fake instant solver, thousands of tiny points.
for order in asc greedy; do
  start_server "$work/fake-$order" "$work/fake-$order.log"
  "$bin/service-bench" "$url" scenes/three-blocks-tiny.toml "$pools" nearest "$order" "${fake_grid[@]}"
done
