#!/usr/bin/env bash
# Strong scaling with each rank's time split (`solve --profile`), on a node of many cores: the
# run behind docs/performance.md, "Where a rank's time goes". One command, under 10 minutes on a
# 16-core node; each run's JSON is written as soon as it ends, so a cut run keeps what it did.
#
#   deploy/bundle-worker.sh target/glissade-worker-bundle.tgz          # on the build machine
#   tools/perf/mpi-profile-device.sh target/glissade-worker-bundle.tgz OUT_DIR [RUNS]
#
# RUNS: space-separated RANKS:THREADS pairs (THREADS: GLISSADE_SOLVER_THREADS of each rank);
# the default puts first what the table needs most. SCENE, ITERATIONS and SCALE may be set in
# the environment (three-blocks-paper, 3, multi); DEADLINE (seconds since the epoch) skips the
# runs that would start after it and cuts the last one there; HUNG_GRACE (20 s) is how long
# ranks may take to end after the answer is out.
set -euo pipefail
bundle=${1:?usage: mpi-profile-device.sh BUNDLE.tgz OUT_DIR [RUNS]}
out=${2:?usage: mpi-profile-device.sh BUNDLE.tgz OUT_DIR [RUNS]}
runs=${3:-"16:1 1:16 1:1 8:1 4:1 2:1 16:16"}
scene=${SCENE:-scenes/three-blocks-paper.toml}
iterations=${ITERATIONS:-3}
scale=${SCALE:-multi}
g=$(mktemp -d)
tar xzf "$bundle" -C "$g"
export LD_LIBRARY_PATH=$g/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH} PATH=$g/bin:$PATH
mkdir -p "$out"
{ nproc; lscpu 2>/dev/null | grep -E 'Model name|Thread|NUMA node\(s\)' || true; } > "$out/node.txt"
for run in $runs; do
  p=${run%%:*} threads=${run##*:}
  name="$(basename "$scene" .toml)-$scale-p$p-t$threads"
  limit=${RUN_TIMEOUT:-200}
  if [[ -n ${DEADLINE:-} ]]; then
    left=$(( DEADLINE - $(date +%s) ))
    if (( left < 15 )); then echo "$name: skipped (deadline)" | tee -a "$out/runs.txt"; continue; fi
    (( left < limit )) && limit=$left
  fi
  start=$(date +%s.%N)
  # exit 2 is "not converged": expected, the tolerance is out of reach on purpose. A run whose
  # answer is out but whose ranks have not ended HUNG_GRACE s later is recorded as hung at exit (ranks'
  # states in NAME.hung) and ended: it has its figures, and the node's time is not spent waiting.
  GLISSADE_SOLVER_THREADS=$threads timeout "$limit" mpiexec -launcher fork -n "$p" \
    glissade-worker solve "$scene" --scale "$scale" --tol 1e-10 --max-iter "$iterations" --profile --json \
    > "$out/current.json" 2> >(sed "s/^/$name: /" >> "$out/stderr.txt") &
  job=$!
  answered=
  while kill -0 "$job" 2>/dev/null; do
    if [[ -z $answered ]] && grep -q '"profile"' "$out/current.json" 2>/dev/null; then answered=$(date +%s); fi
    if [[ -n $answered ]] && (( $(date +%s) - answered > ${HUNG_GRACE:-20} )); then
      { echo "== $name"; ps -eo pid,stat,pcpu,wchan:32,etimes,args | grep -E 'glissade-worker|mpiexec|hydra' | grep -v grep; } >> "$out/hung.txt"
      for pid in $(pgrep -f 'glissade-worker solve'); do
        echo "== $pid"; cat "/proc/$pid/stack" 2>/dev/null | head -20; ls "/proc/$pid/task" 2>/dev/null | wc -l
      done >> "$out/hung.txt" 2>&1
      pkill -f 'glissade-worker solve' || true
      break
    fi
    sleep 1
  done
  wait "$job" 2>/dev/null && rc=0 || rc=$?
  [[ $rc -eq 0 || $rc -eq 2 ]] || echo "$name: exit $rc${answered:+ (answered, then hung at exit)}" >> "$out/failures.txt"
  # the answer's line (mpiexec may add its own lines after a killed job), named
  grep -m1 '^{' "$out/current.json" | sed "s/^{/{\"run\":\"$name\",/" >> "$out/runs.jsonl" || true
  rm -f "$out/current.json"
  echo "$name: $(awk "BEGIN { printf \"%.1f\", $(date +%s.%N) - $start }") s" | tee -a "$out/runs.txt"
done
