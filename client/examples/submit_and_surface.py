#!/usr/bin/env python3
"""Submit a grid study to a glissade coordinator, follow it, and print its response surface.

The gRPC API from outside Rust: the stubs are generated at run time from the contract,
proto/proto/glissade.proto, into a temporary directory, so nothing but two PyPI packages is needed:

    python3 -m venv venv && venv/bin/pip install grpcio grpcio-tools
    venv/bin/python client/examples/submit_and_surface.py --server 127.0.0.1:50051 \\
        scenes/three-blocks-tiny.toml --grid f1=0.1:0.2:3 --grid f2=0.1:0.2:3 --tol 1e-3

Prints one line per finished point while the study runs (on stderr), then the surface: a CSV
table on stdout (parameters, then QoIs), or one JSON object with --json. Exit status 0 when every
point converged, 1 on an error (one line on stderr), 2 when the study ended with failed points.
"""

import argparse
import importlib
import json
import os
import sys
import tempfile

import grpc
from grpc_tools import protoc

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_PROTO = os.path.join(HERE, "..", "..", "proto", "proto", "glissade.proto")


def load_stubs(proto_path):
    """Generates glissade_pb2 and glissade_pb2_grpc from the .proto and imports them."""
    proto_path = os.path.abspath(proto_path)
    out = tempfile.mkdtemp(prefix="glissade-stubs-")
    # grpc_tools ships the well-known types' .proto files; they are not used by glissade.proto
    # but protoc wants the include path of its own installation.
    well_known = os.path.join(os.path.dirname(protoc.__file__), "_proto")
    status = protoc.main([
        "grpc_tools.protoc",
        f"-I{os.path.dirname(proto_path)}",
        f"-I{well_known}",
        f"--python_out={out}",
        f"--grpc_python_out={out}",
        os.path.basename(proto_path),
    ])
    if status != 0:
        raise RuntimeError(f"protoc failed on {proto_path}")
    sys.path.insert(0, out)
    return importlib.import_module("glissade_pb2"), importlib.import_module("glissade_pb2_grpc")


def read_token(path):
    """The user token: the file given, else GLISSADE_TOKEN, else the file GLISSADE_TOKEN_FILE names."""
    if path is None and "GLISSADE_TOKEN" in os.environ:
        return os.environ["GLISSADE_TOKEN"].strip()
    path = path or os.environ.get("GLISSADE_TOKEN_FILE")
    if path is None:
        return None
    with open(path, encoding="ascii") as f:
        return f.read().strip()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene", help="scene file (TOML)")
    parser.add_argument("--server", default=os.environ.get("GLISSADE_SERVER", "127.0.0.1:50051"),
                        help="coordinator address, host:port (default: $GLISSADE_SERVER or 127.0.0.1:50051)")
    parser.add_argument("--grid", action="append", required=True, metavar="NAME=SPEC",
                        help="swept parameter, e.g. f1=0.1:0.2:3 (repeatable)")
    parser.add_argument("--tol", type=float, help="tolerance on the error indicator (default: the scene's)")
    parser.add_argument("--strategy", choices=["cold", "previous", "nearest", "blend", "linear"],
                        help="where each point starts (default: the coordinator's, linear with 8 neighbours)")
    parser.add_argument("--timeout", type=float, default=600.0, help="give up after this many seconds")
    parser.add_argument("--proto", default=DEFAULT_PROTO, help="path of glissade.proto")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of CSV")
    parser.add_argument("--token-file", help="file holding the user token of a coordinator that asks for one "
                        "(else GLISSADE_TOKEN, else the file GLISSADE_TOKEN_FILE names), as the CLI reads it")
    parser.add_argument("--ca-cert", default=os.environ.get("GLISSADE_CA_CERT"),
                        help="PEM certificate of the authority that signed an https:// coordinator's certificate")
    args = parser.parse_args()
    token = read_token(args.token_file)
    md = (("authorization", f"Bearer {token}"),) if token else ()

    pb, rpc = load_stubs(args.proto)
    with open(args.scene, encoding="utf-8") as f:
        scene = f.read()
    if args.server.startswith("https://"):
        root = open(args.ca_cert, "rb").read() if args.ca_cert else None
        channel = grpc.secure_channel(args.server.removeprefix("https://"), grpc.ssl_channel_credentials(root))
    else:
        channel = grpc.insecure_channel(args.server.removeprefix("http://"))
    with channel:
        user = rpc.UserStub(channel)
        request = pb.SubmitStudyRequest(
            scene=scene,
            grid=args.grid,
            strategy=pb.InitStrategy.Value("INIT_STRATEGY_" + (args.strategy or "unspecified").upper()),
        )
        if args.tol is not None:
            request.tolerance = args.tol
        reply = user.SubmitStudy(request, timeout=30, metadata=md)
        print(f"study {reply.study_id}: {reply.points} points of scene {reply.scene_hash[:12]}...",
              file=sys.stderr)

        # Follow the study until it ends: a server stream of events.
        for event in user.WatchStudy(pb.WatchStudyRequest(study_id=reply.study_id), timeout=args.timeout,
                                    metadata=md):
            if event.kind == pb.EVENT_KIND_POINT_FINISHED and not event.replay:
                p = event.point
                where = " ".join(f"{k}={v:g}" for k, v in sorted(p.parameters.items()))
                print(f"  done {event.progress.done}/{event.progress.total}: {where}: "
                      f"{p.iterations} iterations, eta {p.error_indicator:.2e}", file=sys.stderr)
            if event.kind == pb.EVENT_KIND_STUDY_ENDED:
                break

        surface = user.QuerySurface(pb.QuerySurfaceRequest(study_id=reply.study_id), timeout=30, metadata=md)
        study = user.GetStudy(pb.GetStudyRequest(study_id=reply.study_id), timeout=30, metadata=md)

    rows = [
        {
            "parameters": dict(sorted(p.parameters.items())),
            "qoi": dict(sorted(p.qoi.items())),
            "iterations": p.iterations,
            "error_indicator": p.error_indicator,
            "converged": p.converged,
        }
        for p in surface.points
    ]
    if args.json:
        print(json.dumps({
            "study_id": reply.study_id,
            "scene_hash": surface.scene_hash,
            "state": pb.StudyState.Name(study.state),
            "parameters": list(surface.parameters),
            "qoi": list(surface.qoi),
            "points": rows,
        }))
    else:
        print(",".join(list(surface.parameters) + list(surface.qoi) + ["iterations", "error_indicator"]))
        for r in rows:
            values = [r["parameters"][n] for n in surface.parameters] + [r["qoi"].get(q, "") for q in surface.qoi]
            print(",".join(str(v) for v in values + [r["iterations"], r["error_indicator"]]))
    return 0 if study.state == pb.STUDY_STATE_DONE else 2


if __name__ == "__main__":
    try:
        sys.exit(main())
    except grpc.RpcError as e:
        print(f"error: {e.details()} ({e.code().name})", file=sys.stderr)
        sys.exit(1)
    except (OSError, RuntimeError) as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(1)
