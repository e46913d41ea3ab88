#!/bin/bash
# Compares one LATIN iteration of this tree's build with an older commit's, in one run on this
# machine: both builds of solver/examples/iteration_cost.rs (this tree's source, copied into the
# old tree, so both measure alike), run alternately REPS times (docs/performance.md, "Why an
# iteration got slower").
#   tools/perf/iteration-cost-builds.sh OLD_COMMIT [SCENE] [ITERATIONS] [REPS]
# A tree from before the solver moved out of the worker (9287b97, 2026-11-23) takes the example
# with its crate paths renamed; the script was checked on 9287b97 only.
set -euo pipefail
old=$1
scene=${2:-scenes/three-blocks-small.toml}
iterations=${3:-20}
reps=${4:-5}
root=$(git rev-parse --show-toplevel)
cd "$root"
# release builds of both trees share one target directory (under the ignored target/)
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$root/target/compare}"
scratch="$root/../$(basename "$root")-compare-old"
out=$(mktemp -d)
git worktree add --detach "$scratch" "$old" >/dev/null
trap 'git worktree remove --force "$scratch"; rm -rf "$out"' EXIT

nice -n 10 cargo build -q --release -p glissade-solver --example iteration_cost
cp "$CARGO_TARGET_DIR/release/examples/iteration_cost" "$out/new"
if [ -d "$scratch/solver" ]; then
  cp solver/examples/iteration_cost.rs "$scratch/solver/examples/"
  (cd "$scratch" && nice -n 10 cargo build -q --release -p glissade-solver --example iteration_cost)
else
  sed -e '/^use glissade_core::point::DesignPoint;$/d' \
    -e 's/glissade_core::scene/glissade_worker::scene/g; s/glissade_solver::/glissade_worker::/g' \
    -e 's/parameter_values(&DesignPoint::new())/parameter_values(\&[])/' \
    -e 's/Scene::read(std::path::Path::new(&path)).expect("scene")/Scene::parse(\&std::fs::read_to_string(\&path).expect("read scene")).expect("scene")/' \
    solver/examples/iteration_cost.rs > "$scratch/worker/examples/iteration_cost.rs"
  (cd "$scratch" && nice -n 10 cargo build -q --release -p glissade-worker --example iteration_cost)
fi
cp "$CARGO_TARGET_DIR/release/examples/iteration_cost" "$out/old"

for r in $(seq 1 "$reps"); do
  for build in old new; do
    echo "== $build ($( [ $build = old ] && echo "$old" || git rev-parse --short HEAD)) run $r, load $(cut -d' ' -f1-4 /proc/loadavg)"
    nice -n 10 "$out/$build" "$scene" "$iterations"
  done
done
