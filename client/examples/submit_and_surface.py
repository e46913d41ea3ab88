#!/usr/bin/env python3
"""Submit a grid study to a glissade coordinator, follow it, and print its response surface.

A user of the glissade Python package (client/python; its gRPC stubs are generated from
proto/proto/glissade.proto when it is installed):

    python3 -m venv venv && venv/bin/pip install ./client/python
    venv/bin/python client/examples/submit_and_surface.py --server http://127.0.0.1:50051 \\
        scenes/three-blocks-tiny.toml --grid f1=0.1:0.2:3 --grid f2=0.1:0.2:3 --tol 1e-3

Prints one line per finished point while the study runs (on stderr), then the surface: a CSV
table on stdout (parameters, then QoIs), or one JSON object with --json. Exit status 0 when every
point converged, 1 on an error (one line on stderr), 2 when the study ended with failed points.
"""

import argparse
import json
import os
import sys

import glissade


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene", help="scene file (TOML); the mesh files it names travel with it")
    parser.add_argument("--server", default=os.environ.get("GLISSADE_SERVER", "http://127.0.0.1:50051"),
                        help="coordinator URL (default: $GLISSADE_SERVER or http://127.0.0.1:50051)")
    parser.add_argument("--grid", action="append", required=True, metavar="NAME=SPEC",
                        help="swept parameter, e.g. f1=0.1:0.2:3 (repeatable)")
    parser.add_argument("--tol", type=float, help="tolerance on the error indicator (default: the scene's)")
    parser.add_argument("--strategy", choices=["cold", "previous", "nearest", "blend", "linear"],
                        help="where each point starts (default: the coordinator's, linear with 3 neighbours)")
    parser.add_argument("--timeout", type=float, default=600.0, help="give up after this many seconds")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of CSV")
    parser.add_argument("--token-file", help="file holding the user token of a coordinator that asks for one "
                        "(else GLISSADE_TOKEN, else the file GLISSADE_TOKEN_FILE names), as the CLI reads it")
    parser.add_argument("--ca-cert", help="PEM certificate of the authority that signed an https:// "
                        "coordinator's certificate (else GLISSADE_CA_CERT)")
    args = parser.parse_args()
    grid = dict(g.split("=", 1) for g in args.grid)

    with glissade.Client(args.server, token_file=args.token_file, ca_cert=args.ca_cert) as client:
        study = client.submit(args.scene, grid=grid, tol=args.tol, strategy=args.strategy)
        print(f"study {study.study_id}: {study.points} points of scene {study.scene_hash[:12]}...", file=sys.stderr)
        for event in client.watch(study, timeout=args.timeout):
            if event.kind == "point_finished" and not event.replay:
                p = event.point
                where = " ".join(f"{k}={v:g}" for k, v in sorted(event.parameters.items()))
                print(f"  done {event.done}/{event.total}: {where}: "
                      f"{p.iterations} iterations, eta {p.error_indicator:.2e}", file=sys.stderr)
        surface = client.surface(study)
        state = client.study(study).state

    names, qois = surface.attrs["parameters"], surface.attrs["qoi"]
    if args.json:
        print(json.dumps({
            "study_id": study.study_id,
            "scene_hash": surface.attrs["scene_hash"],
            "state": glissade.pb.StudyState.Name(state),
            "parameters": names,
            "qoi": qois,
            "points": [
                {
                    "parameters": {n: row[n] for n in names},
                    "qoi": {q: row[q] for q in qois if row[q] == row[q]},  # NaN: none
                    "iterations": int(row["iterations"]),
                    "error_indicator": row["error_indicator"],
                    "converged": bool(row["converged"]),
                }
                for row in surface.to_dict("records")
            ],
        }))
    else:
        surface[names + qois + ["iterations", "error_indicator"]].to_csv(sys.stdout, index=False)
    return 0 if state == glissade.pb.STUDY_STATE_DONE else 2


if __name__ == "__main__":
    try:
        sys.exit(main())
    except glissade.GlissadeError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(1)
