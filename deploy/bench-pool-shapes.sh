#!/usr/bin/env bash
# Same cores, two ways (docs/performance.md, Service): one pool of P ranks (each point solved by
# P ranks together) against P pools of one rank (P points at once). A real coordinator and real
# pools on this machine, release builds; prints the wall time of the whole study and its
# iterations for each shape.
#
#   deploy/bench-pool-shapes.sh [SCENE] [P] [GRID...]
#   deploy/bench-pool-shapes.sh scenes/three-blocks-small.toml 2 f1=0.1:0.2:3 f2=0.1:0.2:3
set -euo pipefail
cd "$(dirname "$0")/.."
scene=${1:-scenes/three-blocks-small.toml}
ranks=${2:-2}
shift 2 || true
grid=("$@")
[[ ${#grid[@]} -gt 0 ]] || grid=(f1=0.1:0.2:3 f2=0.1:0.2:3)
tol=${TOL:-2e-4}

cargo build --release -p glissade-server -p glissade-worker -p glissade
bin=target/release
work=$(mktemp -d)
pids=()
cleanup() { for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done; wait 2>/dev/null; rm -rf "$work"; }
trap cleanup EXIT

run_shape() { # NAME POOLS RANKS_PER_POOL
  local name=$1 pools=$2 per=$3 port_file="$work/$1.port"
  "$bin/glissade-server" --data "$work/$name-db" --listen 127.0.0.1:0 > "$port_file" 2> "$work/$name-server.log" &
  local server=$!
  for _ in $(seq 100); do [[ -s "$port_file" ]] && break; sleep 0.1; done
  local url="http://$(sed 's/listening on //' "$port_file")"
  local args=(--server "$url" submit "$scene" --tol "$tol")
  for g in "${grid[@]}"; do args+=(--grid "$g"); done
  local study start end
  study=$("$bin/glissade" "${args[@]}")
  start=$(date +%s.%N)
  local shape_pids=()
  for i in $(seq "$pools"); do
    mpiexec.mpich -n "$per" "$bin/glissade-worker" pool --coordinator "$url" --pool-id "$name-$i" 2> "$work/$name-pool-$i.log" &
    shape_pids+=($!)
  done
  until "$bin/glissade" --server "$url" show "$study" --json | grep -q '"state":"STUDY_STATE_DONE"'; do sleep 0.2; done
  end=$(date +%s.%N)
  local iterations
  iterations=$("$bin/glissade" --server "$url" show "$study" --json | python3 -c 'import json,sys; print(int(json.load(sys.stdin)["progress"]["iterations"]))')
  printf '%-22s wall %7.1f s   iterations %6d\n' "$pools pool(s) x $per rank(s)" "$(python3 -c "print($end - $start)")" "$iterations"
  for p in "${shape_pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
  kill -TERM "$server" 2>/dev/null || true
  wait "${shape_pids[@]}" "$server" 2>/dev/null || true
}

echo "$scene, grid ${grid[*]}, tol $tol, $(nproc) cores:"
run_shape one "1" "$ranks"
run_shape many "$ranks" "1"
