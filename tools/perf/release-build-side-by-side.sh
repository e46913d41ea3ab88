#!/usr/bin/env bash
# The main command's release build from scratch at two revisions of this repository, side by side:
# each in its own clone and target directory, alternated ROUNDS times (default 2), so that a
# machine whose speed varies by the hour compares like with like (docs/performance.md, "The test
# command"). Prints each build's wall and user time and the sum of its units' times (from cargo's
# --timings report); keeps the logs and reports in OUT_DIR.
#
#   tools/perf/release-build-side-by-side.sh OLD_REV NEW_REV OUT_DIR [ROUNDS]
#   tools/perf/release-build-side-by-side.sh be200ae 5810909 /tmp/pair       # 4 builds, ~25 min on 2 cores
set -euo pipefail
old=${1:?usage: release-build-side-by-side.sh OLD_REV NEW_REV OUT_DIR [ROUNDS]}
new=${2:?usage: release-build-side-by-side.sh OLD_REV NEW_REV OUT_DIR [ROUNDS]}
out=${3:?usage: release-build-side-by-side.sh OLD_REV NEW_REV OUT_DIR [ROUNDS]}
rounds=${4:-2}
repo=$(cd "$(dirname "$0")/../.." && pwd)
mkdir -p "$out"
for rev in "$old" "$new"; do
  rm -rf "$out/$rev"
  git clone -q "$repo" "$out/$rev"
  git -C "$out/$rev" checkout -q "$rev"
done
for round in $(seq "$rounds"); do
  for rev in "$old" "$new"; do
    (
      cd "$out/$rev"
      rm -rf target
      /usr/bin/time -f "%e %U" -o "$out/$rev.$round.time" \
        cargo build --release -p glissade -p glissade-server -p glissade-worker --timings > "$out/$rev.$round.log" 2>&1
      cp target/cargo-timings/cargo-timing.html "$out/$rev.$round.html"
    )
    python3 - "$out/$rev.$round.html" "$out/$rev.$round.time" "$rev" "$round" <<'PY'
import json, re, sys
report, times, rev, round_ = sys.argv[1:]
units = json.loads(re.search(r"const UNIT_DATA = (\[.*?\]);\n", open(report).read(), re.S).group(1))
wall, user = open(times).read().split()[-2:]
print(f"{rev} round {round_}: {float(wall):.1f} s wall, {float(user):.0f} CPU-s user, units summed {sum(u['duration'] for u in units):.1f} CPU-s", flush=True)
PY
  done
done
