#!/usr/bin/env bash
# Bundles the release glissade-worker with MPICH's mpiexec and every shared library they need,
# so a cluster user without admin rights can run it on a node without MPICH or HDF5 installed:
#
#   deploy/bundle-worker.sh [OUT.tgz]          # on the build machine (after install-deps.sh)
#   mkdir -p /tmp/g && tar xzf glissade-worker-bundle.tgz -C /tmp/g
#   export LD_LIBRARY_PATH=/tmp/g/lib PATH=/tmp/g/bin:$PATH
#   mpiexec -launcher fork -n 16 glissade-worker solve SCENE.toml      # on the node
#
# With --service the coordinator (glissade-server) and the CLI (glissade) come too, for a study
# through the service on one node (tools/perf/study-device.sh).
set -euo pipefail
out=${1:-glissade-worker-bundle.tgz}
service=${2:-}
cd "$(dirname "$0")/.."
if [[ $service == --service ]]; then
  cargo build --release -p glissade-worker -p glissade-server -p glissade
else
  cargo build --release -p glissade-worker
fi
stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT
mkdir -p "$stage/bin" "$stage/lib" "$stage/scenes"
cp target/release/glissade-worker "$stage/bin/"
[[ $service == --service ]] && cp target/release/glissade-server target/release/glissade "$stage/bin/"
cp -L "$(command -v mpiexec.hydra)" "$stage/bin/mpiexec"
cp -L "$(command -v hydra_pmi_proxy)" "$stage/bin/"
cp scenes/*.toml "$stage/scenes/"
for b in "$stage"/bin/*; do
  for lib in $(ldd "$b" | awk '/=>/ {print $3}'); do
    case $(basename "$lib") in
      # the C runtime must come from the node itself
      libc.so*|libm.so*|libgcc_s*|ld-linux*|libresolv*|libpthread*|libdl.so*|librt.so*) ;;
      *) cp -nL "$lib" "$stage/lib/" ;;
    esac
  done
done
strip "$stage"/bin/glissade*
tar czf "$out" -C "$stage" .
echo "bundle: $out ($(du -h "$out" | cut -f1)); run: mpiexec -launcher fork -n P bin/glissade-worker solve ..."
