"""Build hook: the gRPC stubs are generated from the one contract, proto/proto/glissade.proto.

`pip install ./client/python` builds in place (pip >= 21.3), so the contract is found two
folders up, in the checkout. Elsewhere:
- a source distribution (`python -m build`) carries a copy of the contract made when it is
  packed (proto/glissade.proto inside it), so a wheel builds from it anywhere;
- GLISSADE_PROTO=/path/to/glissade.proto names the contract explicitly (an old pip that copies
  the folder to a temporary directory, or a copy of this folder outside the checkout).

The stubs land in glissade/proto/ (ignored by git) as glissade.proto.glissade_pb2 and
glissade.proto.glissade_pb2_grpc: the .proto is compiled under the virtual path
glissade/proto/, so the service module imports its messages from the package, not from a
top-level module.
"""

import os
import shutil

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist

HERE = os.path.dirname(os.path.abspath(__file__))
PACKED = os.path.join("proto", "glissade.proto")  # the copy inside a source distribution


def find_proto():
    candidates = [
        os.environ.get("GLISSADE_PROTO"),
        os.path.join(HERE, "..", "..", "proto", "proto", "glissade.proto"),
        os.path.join(HERE, PACKED),
    ]
    for path in candidates:
        if path and os.path.isfile(path):
            return os.path.abspath(path)
    raise SystemExit(
        "glissade: cannot find glissade.proto (looked at "
        + ", ".join(p for p in candidates if p)
        + "); build from the glissade checkout (pip install ./client/python with pip >= 21.3) "
        "or set GLISSADE_PROTO=/path/to/proto/proto/glissade.proto"
    )


def generate_stubs():
    """Runs protoc (from grpcio-tools) on the contract into glissade/proto/."""
    from grpc_tools import protoc

    proto = find_proto()
    well_known = os.path.join(os.path.dirname(protoc.__file__), "_proto")
    args = [
        "grpc_tools.protoc",
        f"-Iglissade/proto={os.path.dirname(proto)}",
        f"-I{well_known}",
        f"--python_out={HERE}",
        f"--pyi_out={HERE}",
        f"--grpc_python_out={HERE}",
        "glissade/proto/glissade.proto",
    ]
    if protoc.main(args) != 0:
        raise SystemExit(f"glissade: protoc failed on {proto}")


class BuildPy(build_py):
    def run(self):
        generate_stubs()
        super().run()


class Sdist(sdist):
    def make_release_tree(self, base_dir, files):
        super().make_release_tree(base_dir, files)
        os.makedirs(os.path.join(base_dir, "proto"), exist_ok=True)
        shutil.copyfile(find_proto(), os.path.join(base_dir, PACKED))


def dependencies():
    """At least the grpcio and protobuf the stubs were generated with (their version checks)."""
    deps = ["numpy", "pandas", 'tomli; python_version < "3.11"']
    from importlib.metadata import PackageNotFoundError, version

    try:
        deps += [f"grpcio>={version('grpcio-tools')}", f"protobuf>={version('protobuf')}"]
    except PackageNotFoundError:  # metadata read without the build requirements
        deps += ["grpcio", "protobuf"]
    return deps


setup(
    install_requires=dependencies(),
    cmdclass={"build_py": BuildPy, "sdist": Sdist},
    package_data={"glissade.proto": ["*.pyi"], "glissade": ["py.typed"]},
)
