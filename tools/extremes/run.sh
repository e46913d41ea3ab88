#!/usr/bin/env bash
# Issue 30's cases at the default settings, at 2e-4 and 1e-5: one line a solve (converged,
# work in sweeps, iterations, the window check's outcome, the estimate, wall time, final QoIs).
# The table in docs/performance.md, "Where issue 30's cases stand at the default settings".
#   cargo build --release -p glissade-worker
#   bash tools/extremes/run.sh [OUT_DIR]        (about 10-20 minutes on two cores)
# With PRAKASH_CLIFTON="LENGTH VELOCITY" every friction interface is given that regularisation
# (docs/verification.md 4e; the table "... with the Prakash-Clifton law").
# With CASES="asp 0.4;sb_x1 6" only those cases (scene and f, separated by ';').
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
W=${GLISSADE_WORKER:-$here/../../target/release/glissade-worker}
out=${1:-$(mktemp -d)}
mkdir -p "$out"
one() { # label scene f tol
  scene="$here/$2.toml"
  if [[ -n "${PRAKASH_CLIFTON:-}" ]]; then
    set -- "$@" $PRAKASH_CLIFTON
    scene="$out/$2.toml"
    sed "s/^friction = \(.*\)/friction = \1\nprakash_clifton = { length = $5, velocity = $6 }/" "$here/$2.toml" >"$scene"
  fi
  "$W" solve "$scene" --set "f=$3" --tol "$4" --json >"$out/$1.json" 2>"$out/$1.err" || true
  python3 - "$out/$1" "$2" "$3" "$4" <<'PY'
import json, sys
l, s, f, t = sys.argv[1:]
try:
    d = json.load(open(l + '.json'))
except Exception:
    print(f"{l}\t{s}\tf={f}\ttol={t}\tNO RESULT: " + open(l + '.err').read()[-200:].replace('\n', ' '))
    sys.exit()
st = d['static_stage']['iterations'] if d.get('static_stage') else 0
work = d['dynamic_sweeps'] + st / max(1, d['time_steps'])
c = d.get('window_check') or {}
print(f"{l.split('/')[-1]}\tconverged={d['converged']}\twork={work:.1f}\tit={d['iterations']}\t"
      f"check={c.get('outcome', '-')}/{c.get('passes', '-')}\test={d['error_estimate']:.2e}\twall={d['wall_seconds']:.1f}\t"
      + " ".join(f"{k}={v['final']:.5e}" for k, v in d['qoi'].items()))
PY
}
all=("sb_x1 0.4" "sb_d2 0.4" "sb_d4 0.4" "sb_d10 0.4" "sb_x1 0.2" "sb_d10 0.2" "sb_x1 1" "sb_x1 6" "sb_x1 10"
     "one_el 0.4" "fine 0.4" "asp 0.4" "nu499 0.4" "nu4999 0.4" "twob 0.2" "twob10 0.2" "sb3d 0.25")
if [[ -n "${CASES:-}" ]]; then IFS=';' read -r -a all <<<"$CASES"; fi
for tol in 2e-4 1e-5; do
  for c in "${all[@]}"; do
    set -- $c
    one "${1}_f${2}_t$tol" "$1" "$2" "$tol"
  done
done
echo "JSON and stderr of every solve in $out"
