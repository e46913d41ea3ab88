#!/usr/bin/env bash
# The coordinator's resident memory as stored points accumulate (docs/performance.md, "Memory per
# design point"): N studies of 2,000 points of three-blocks-tiny, one after the other, each solved
# by 4 fake pools with an instant solver (service-bench --no-web: no page is built), VmRSS and the
# database's size printed after each.
#   cargo build --release -p glissade-server -p glissade-e2e --bins
#   bash tools/perf/memory-per-point.sh [SERVER_BIN] [STUDIES]   # defaults: target/release/glissade-server 25
set -euo pipefail
cd "$(dirname "$0")/../.."
server=${1:-target/release/glissade-server}
studies=${2:-25}
dir=$(mktemp -d)
trap 'kill "$pid" 2>/dev/null || true; rm -rf "$dir"' EXIT
"$server" --listen 127.0.0.1:0 --data "$dir/db" --max-points 1000000 --max-pending 1000000 >"$dir/out" 2>"$dir/log" &
pid=$!
for _ in $(seq 50); do grep -q "listening on" "$dir/out" 2>/dev/null && break; sleep 0.1; done
addr=$(sed -n 's/^listening on //p' "$dir/out")
rss() { awk '/VmRSS/ {printf "%.1f MiB", $2 / 1024}' "/proc/$pid/status"; }
echo "start: $(rss)"
for k in $(seq "$studies"); do
  target/release/service-bench --no-web "http://$addr" scenes/three-blocks-tiny.toml 4 cold asc \
    f1=0.1:0.2:50 f2=0.1:0.2:40 >/dev/null
  echo "after $((k * 2000)) points: $(rss), database $(du -sh "$dir/db" | cut -f1)"
done
