#!/usr/bin/env bash
# Installs every Debian package glissade's build and tests need. Idempotent, no stdin, run as root.
# Takes seconds when everything is present; fails loudly when something cannot be installed.
set -euo pipefail

PACKAGES=(
  build-essential pkg-config ca-certificates
  mpich libmpich-dev          # MPI (hydra mpiexec), rsmpi links against it
  libhdf5-dev                 # HDF5 field output (hdf5-metno finds it through pkg-config)
  libzstd-dev                 # the stored solutions' compression (zstd-sys links it through pkg-config)
  protobuf-compiler           # protoc for tonic/prost code generation
  libclang-dev                # bindgen, used by mpi-sys
  python3 python3-venv        # the Python gRPC example client (its test pip-installs grpcio,
                              # grpcio-tools, grpcio-reflection from PyPI into a venv under
                              # target/)
  python3-h5py python3-numpy  # an independent reader of `glissade fields` output in the tests
  openssl                     # the TLS test makes a certificate authority with it
  chromium                    # the web page's test loads it in a real (headless) browser
  slurm-wlm munge             # a real one-node Slurm for the batch files' test
                              # (deploy/slurm/one-node-cluster.sh starts daemons of its own)
)

missing=()
for p in "${PACKAGES[@]}"; do
  # dpkg-query prints "install ok installed" only for a fully installed package.
  if [[ "$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null || true)" != "install ok installed" ]]; then
    missing+=("$p")
  fi
done

if ((${#missing[@]} == 0)); then
  echo "install-deps: all ${#PACKAGES[@]} packages present"
else
  if [[ $(id -u) -ne 0 ]]; then
    echo "install-deps: missing packages (${missing[*]}) and not root; rerun as root" >&2
    exit 1
  fi
  echo "install-deps: installing ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  # No daemon starts from a package's install script (munge and slurm-wlm would start munged,
  # slurmctld and slurmd as system services): a policy-rc.d that refuses, for the install only,
  # unless the machine has one (Debian's container images do).
  policy=/usr/sbin/policy-rc.d
  if [[ ! -e $policy ]]; then
    printf '#!/bin/sh\n# deploy/install-deps.sh: no service starts during its install\nexit 101\n' > "$policy"
    chmod 755 "$policy"
    trap 'rm -f "$policy"' EXIT
  fi
  apt-get update -q
  apt-get install -y -q --no-install-recommends "${missing[@]}"
fi

# The test command checks formatting and lints: rustfmt and clippy, added to the toolchain when
# they are missing (no download when present).
for component in rustfmt clippy; do
  cmd=${component/rustfmt/fmt}
  if ! cargo "$cmd" --version >/dev/null 2>&1; then
    command -v rustup >/dev/null || { echo "install-deps: cargo $cmd missing and no rustup to add it" >&2; exit 1; }
    rustup component add "$component"
  fi
done

# Check the tools the build actually calls, so a broken install fails here and not mid-build.
for tool in mpiexec mpicc protoc pkg-config chromium sbatch srun; do
  command -v "$tool" >/dev/null || { echo "install-deps: '$tool' not found after install" >&2; exit 1; }
done
# the daemons, in /usr/sbin (not on a user's PATH)
for daemon in munged slurmctld slurmd; do
  command -v "$daemon" >/dev/null || [[ -x /usr/sbin/$daemon ]] ||
    { echo "install-deps: '$daemon' not found after install" >&2; exit 1; }
done
pkg-config --exists hdf5 || { echo "install-deps: pkg-config cannot find hdf5" >&2; exit 1; }
# Hydra's `mpiexec --version` starts with "HYDRA build details:"; the MPI version is on its
# "Version:" line.
mpi_version=$(mpiexec --version 2>/dev/null | awk '$1 == "Version:" {print $2; exit}')
echo "install-deps: ok (MPICH ${mpi_version:-unknown version}, $(protoc --version), HDF5 $(pkg-config --modversion hdf5))"
