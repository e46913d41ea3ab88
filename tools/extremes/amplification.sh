#!/usr/bin/env bash
# How fast a sliding block's motion amplifies a difference (docs/verification.md, "A slide that
# amplifies perturbations"): the scene marched a step a window (time_window = 1, no check), each
# step converged to 1e-10 and to 1e-7, and the two QoI histories compared: where their
# difference first reaches 1e-7 and 1e-4 of the QoI's largest value, and the growth rate between.
#   cargo build --release -p glissade-worker
#   bash tools/extremes/amplification.sh SCENE STEPS NU F      e.g. tools/extremes/sb_x1.toml 600 0.499 0.4
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
W=${GLISSADE_WORKER:-$here/../../target/release/glissade-worker}
scene=$1 steps=$2 nu=$3 f=$4
out=$(mktemp -d)
sed "s/^\[solver\]/[solver]\ntime_window = 1\nmax_iterations = 20000\nwindow_check = false/; s/^steps = .*/steps = $steps/; s/^nu = .*/nu = $nu/" \
  "$scene" >"$out/scene.toml"
for t in 1e-10 1e-7; do "$W" solve "$out/scene.toml" --set "f=$f" --tol "$t" --json >"$out/$t.json" 2>/dev/null || true; done
python3 - "$out" "$(basename "$scene" .toml) steps=$steps nu=$nu f=$f" <<'PY'
import json, math, sys
out, tag = sys.argv[1:]
a, b = (json.load(open(f"{out}/{t}.json")) for t in ("1e-10", "1e-7"))
for q in a["qoi"]:
    ha, hb, t = a["qoi"][q]["values"], b["qoi"][q]["values"], a["qoi"][q]["times"]
    scale = max(abs(v) for v in ha)
    m, running = 0.0, []
    for x, y in zip(ha, hb):
        m = max(m, abs(x - y) / scale)
        running.append(m)
    i = next((k for k, v in enumerate(running) if v > 1e-7), None)
    j = next((k for k, v in enumerate(running) if v > 1e-4), None)
    rate = math.log(running[j] / running[i]) / (t[j] - t[i]) if i is not None and j is not None and j > i else float("nan")
    print(f"{tag} {q}: converged {a['converged']}/{b['converged']}; largest difference {running[-1]:.2e}, "
          f"final {abs(ha[-1] - hb[-1]) / scale:.2e}; 1e-7 at t = {t[i] if i is not None else float('nan'):.3e} s, "
          f"1e-4 at {t[j] if j is not None else float('nan'):.3e} s; growth {rate:.2e} /s")
PY
rm -r "$out"
