#!/usr/bin/env bash
# Issue 49's measurements on a lent 16-core node, as one command inside BUDGET seconds (default
# 540): the node's memory bandwidth (tools/perf/bandwidth.py), strong scaling of three-blocks-paper (multiscale, one thread a rank, each rank's time split
# by `solve --profile`), then the paper-size study through the service on one 16-rank pool for
# what time is left (tools/perf/study-device.sh), then single scale at 16 and 1 ranks and one rank
# with 16 threads if time remains. Every part keeps what it measured when the time runs out;
# the results end in OUT_DIR/results.tgz, the tables' inputs beside it.
#
#   deploy/bundle-worker.sh target/bundle.tgz --service                       # here
#   tools/perf/node-scaling-and-study.sh target/bundle.tgz OUT_DIR [BUDGET]   # on the node
#   python3 tools/perf/mpi-profile-table.py OUT_DIR/multi                     # the tables
#
# STUDY_SECONDS (300) bounds the study; RANKS ("16 8 4 2 1") the scaling runs; SCENE
# (three-blocks-paper), STUDY_RANKS (16) and STUDY_GRID ("f1=0.1:0.2:11 f2=0.1:0.2:11") make a
# rehearsal on a small machine possible.
set -euo pipefail
bundle=${1:?usage: node-scaling-and-study.sh BUNDLE.tgz OUT_DIR [BUDGET]}
out=${2:?usage: node-scaling-and-study.sh BUNDLE.tgz OUT_DIR [BUDGET]}
budget=${3:-540}
here=$(cd "$(dirname "$0")" && pwd)
end=$(( $(date +%s) + budget ))
mkdir -p "$out"
work=$(mktemp -d)
g=$(mktemp -d)
tar xzf "$bundle" -C "$g"
pack() { tar czf "$out/results.tgz" -C "$work" . 2>/dev/null || true; }
trap pack EXIT
runs=""; for p in ${RANKS:-16 8 4 2 1}; do runs+="$p:1 "; done
export HUNG_GRACE=5 RUN_TIMEOUT=150

echo "== the node's memory bandwidth (tools/perf/bandwidth.py)" >&2
if python3 -c "import numpy" 2>/dev/null; then
  timeout 90 python3 "$here/bandwidth.py" > "$out/bandwidth.json" || echo "bandwidth: not measured" >&2
else echo "bandwidth: no numpy, not measured" >&2; fi

echo "== scaling, multiscale: $runs" >&2
DEADLINE=$(( end - ${STUDY_SECONDS:-300} )) SCALE=multi "$here/mpi-profile-device.sh" "$bundle" "$work/multi" "$runs" || true
cp "$work/multi/runs.jsonl" "$out/multi.jsonl" 2>/dev/null || true

left=$(( end - $(date +%s) - 90 ))
study=$(( left < ${STUDY_SECONDS:-300} ? left : ${STUDY_SECONDS:-300} ))
if (( study > 60 )); then
  echo "== the paper-size study, $study s" >&2
  "$here/study-device.sh" "$g" "$work/study" "$study" "${STUDY_RANKS:-16}" "${SCENE:-scenes/three-blocks-paper.toml}" \
    ${STUDY_GRID:-f1=0.1:0.2:11 f2=0.1:0.2:11} || true
  cp "$work/study/study.json" "$out/study.json" 2>/dev/null || true
  cp "$work/study/progress.txt" "$out/progress.txt" 2>/dev/null || true
fi

echo "== single scale 16:1 1:1, then 1 rank x 16 threads, as time allows" >&2
DEADLINE=$end SCALE=single "$here/mpi-profile-device.sh" "$bundle" "$work/single" "16:1 1:1" || true
cp "$work/single/runs.jsonl" "$out/single.jsonl" 2>/dev/null || true
DEADLINE=$end SCALE=multi "$here/mpi-profile-device.sh" "$bundle" "$work/threads" "1:16" || true
cp "$work/threads/runs.jsonl" "$out/threads.jsonl" 2>/dev/null || true
cat "$work"/*/runs.txt >&2 2>/dev/null || true
