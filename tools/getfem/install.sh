#!/bin/sh
# Installs GetFEM's Python interface (Debian bookworm: GetFEM 5.4), the optional peer of
# tools/getfem/sliding_block.py. Not run by the project's CI.
set -eu
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
$SUDO apt-get update
$SUDO apt-get install -y python3-getfem
# the Debian package installs into the system Python's dist-packages
/usr/bin/python3 -c 'import getfem; print("getfem", getfem.__version__ if hasattr(getfem, "__version__") else "installed")'
