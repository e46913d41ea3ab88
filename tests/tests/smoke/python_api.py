"""Drives the glissade Python package against a live coordinator (tests/tests/smoke/python.rs).

    python python_api.py mesh URL TOKEN SCENE      submits a meshed scene, cancels it
    python python_api.py main URL TOKEN SCENE OUT  a 2 x 2 grid: submit, watch, surface, predict,
                                                   fetch_solution (written to OUT), the errors
    python python_api.py hostile                   the package against a server that is not ours
                                                   (a real gRPC server on loopback, in this script)
Checks what it can itself (assert) and prints one JSON object for the test to check the rest.
"""

import json
import sys

import numpy as np
import pandas as pd

import glissade


def hostile():
    """A coordinator that answers with a state this package does not know, no prediction, and a
    solution stream that never ends: each must give a clear answer or a GlissadeError, and the
    endless stream must stop before it fills the memory."""
    from concurrent import futures

    import grpc

    pb, pb_grpc = glissade.pb, glissade.pb_grpc
    sent = {"chunks": 0}

    class Hostile(pb_grpc.UserServicer):
        def QuerySurface(self, request, context):
            reply = pb.QuerySurfaceReply(parameters=["f"], qoi=["q"])
            # a point that failed before its first iteration: no indicator, sent as the largest double
            reply.points.add(parameters={"f": 0.1}, qoi={"q": 1.0}, state=77, error_indicator=sys.float_info.max)
            return reply  # no prediction, whatever was asked

        def FetchSolution(self, request, context):
            chunk = b"x" * (1 << 20)
            offset = 0
            while context.is_active() and sent["chunks"] < 10_000:
                sent["chunks"] += 1
                yield pb.SolutionChunk(offset=offset, total_bytes=3 << 20, data=chunk)
                offset += len(chunk)

    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4))
    pb_grpc.add_UserServicer_to_server(Hostile(), server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    result = {}
    try:
        with glissade.Client(f"http://127.0.0.1:{port}", token="t") as c:
            frame = c.surface(1)
            result["state"] = frame["state"].tolist()
            result["eta_is_nan"] = bool(np.isnan(frame["error_indicator"].iloc[0]))
            try:
                c.predict(1, at={"f": 0.1}, qoi="q")
                result["predict"] = "no error"
            except glissade.GlissadeError as e:
                result["predict"] = str(e)
            try:
                c.fetch_solution(1, 0)
                result["fetch"] = "no error"
            except glissade.GlissadeError as e:
                result["fetch"] = str(e)
    finally:
        server.stop(0)
    result["chunks_sent"] = sent["chunks"]
    print(json.dumps(result))


if sys.argv[1] == "hostile":
    hostile()
    sys.exit(0)

mode, url, token, scene = sys.argv[1:5]
out = {}

if mode == "mesh":
    with glissade.Client(url, token=token) as c:
        s = c.submit(scene, grid={"f": [0.3]}, audit=0, refine=0, surface_audit=0)
        out["scene_hash"] = s.scene_hash
        out["cancelled"] = glissade.pb.StudyState.Name(c.cancel(s).state)
    print(json.dumps(out))
    sys.exit(0)

assert mode == "main", mode
with glissade.Client(url, token=token) as c:
    assert c.health()["status"] == "SERVING"
    s = c.submit(scene, grid={"f1": "0.1,0.2", "f2": [0.1, 0.2]}, tol=1e-3, audit=0, refine=0, surface_audit=0)
    assert s.points == 4, s

    events = list(c.watch(s, timeout=120))
    assert events[0].kind == "snapshot", events[0]
    assert events[-1].kind == "study_ended" and events[-1].state == "done", events[-1]
    finished = [e for e in events if e.kind == "point_finished"]
    assert len(finished) == 4 and all(isinstance(e.point, glissade.pb.PointStatus) for e in finished)
    out["finished"] = len(finished)
    out["kinds"] = sorted({e.kind for e in events})

    frame = c.surface(s)
    assert isinstance(frame, pd.DataFrame), type(frame)
    assert list(frame.columns) == ["f1", "f2", "middle_ux", "slip_A", "slip_B", "iterations",
                                   "error_indicator", "converged", "state"], list(frame.columns)
    assert len(frame) == 4 and frame["converged"].all() and (frame["state"] == "done").all(), frame
    assert (frame["error_indicator"] <= 1e-3).all(), frame
    units = frame.attrs["units"]
    assert all(units[q] == "m" for q in ("middle_ux", "slip_A", "slip_B")), units
    one = c.surface(s, qoi="slip_A", fixed={"f2": 0.2})
    assert list(one.columns[:3]) == ["f1", "f2", "slip_A"] and len(one) == 2, one
    arrays = c.surface_arrays(s, qoi="slip_A")
    assert arrays.x.shape == (4, 2) and arrays.y.shape == (4, 1) and np.isfinite(arrays.y).all(), arrays
    assert np.allclose(arrays.y[:, 0], frame["slip_A"].to_numpy())
    out["slip_A"] = frame["slip_A"].tolist()
    # each value as the CLI and the web page write it: the digits the tolerance resolves (1e-3: 4)
    digits, resolutions = frame.attrs["digits"], frame.attrs["resolutions"]
    assert digits == 4 and set(resolutions) == {"middle_ux", "slip_A", "slip_B"}, frame.attrs
    out["study_id"] = s.study_id
    out["texts"] = {q: [glissade.qoi_text(v, digits, resolutions[q]) for v in frame[q]] for q in resolutions}
    exact = c.surface(s, exact=True)
    assert all(((exact[q] == frame[q]) | (exact[q].abs() < resolutions[q])).all() for q in resolutions), (exact, frame)

    # the surface between the points; at a point it was fitted to, close to the solved value
    p = c.predict(s, at={"f1": 0.15, "f2": 0.15}, qoi="slip_A")
    assert isinstance(p, glissade.Prediction) and np.isfinite(p.mean) and p.std >= 0 and p.fitted_points == 4, p
    lo, hi = frame["slip_A"].min(), frame["slip_A"].max()
    assert lo - (hi - lo) <= p.mean <= hi + (hi - lo), (p, lo, hi)
    # its band of 2 sd: a slip's never below zero
    assert p.low == max(0.0, p.mean - 2 * p.std) and p.high == p.mean + 2 * p.std, p
    corner = c.predict(s, at={"f1": 0.1, "f2": 0.1})
    assert set(corner) == {"middle_ux", "slip_A", "slip_B"}, corner
    many = c.predict(s, at=pd.DataFrame({"f1": [0.12, 0.18], "f2": [0.15, 0.15]}), qoi=["slip_A", "slip_B"])
    assert list(many.columns) == [
        "f1", "f2", "slip_A", "slip_A_std", "slip_A_low", "slip_A_high", "slip_B", "slip_B_std", "slip_B_low",
        "slip_B_high"], many
    assert (many["slip_B_low"] >= 0).all(), many
    out["predicted"] = {"mean": p.mean, "std": p.std, "text": str(p)}

    # the study's state and audits by name (none asked here); a study with one iteration audit
    assert c.state(s) == "done" and c.audits(s) == [], c.audits(s)
    assert c.verdicts(s) == [], "no discretisation audit asked: nothing to compare"
    audited = c.submit(scene, grid={"f1": [0.15], "f2": [0.15, 0.2]}, tol=1e-3, audit=1, refine=0, surface_audit=0)
    c.wait(audited, timeout=120)
    audits = c.audits(audited)
    assert [a["what"] for a in audits] == ["iteration"] and audits[0]["total"] == 1, audits
    c.wait(audits[0]["study_id"], timeout=120)
    a = c.audits(audited)[0]
    # solved, or cut by its cost cap (a cheap study at 1e-3 leaves its audit at 1e-5 little), with why
    assert a["state"] == "done" and a["done"] + a["cancelled"] == 1, a
    assert a["cancelled"] == 0 or "cost cap" in a["why_cancelled"], a
    out["audits"] = c.audits(audited)

    # a solution file: by point id and by parameters, the same bytes
    study = c.study(s, points=True)
    first = study.points[0]
    data = c.fetch_solution(s, first.point_id)
    assert data == c.fetch_solution(s, at=dict(first.parameters)), "same point, same bytes"
    assert c.fetch_solution(s, first.point_id, path=sys.argv[5]) == sys.argv[5]
    out["solution"] = {"study_id": s.study_id, "point_id": first.point_id, "bytes": len(data)}

    # errors: exceptions with the gRPC status code and the coordinator's message
    try:
        c.study(999)
        raise AssertionError("unknown study answered")
    except glissade.NotFound as e:
        assert e.code.name == "NOT_FOUND" and "999" in e.message, e
        out["not_found"] = str(e)
    try:
        c.submit(scene, grid={"f1": [0.5]})
        raise AssertionError("out-of-range point accepted")
    except glissade.GlissadeError as e:
        assert e.code_name == "INVALID_ARGUMENT", e
        out["invalid"] = e.message
    # an accuracy reaches the coordinator (which refuses it beside a tolerance it would choose)
    try:
        c.submit(scene, grid={"f1": [0.15]}, accuracy=0.05, tol=1e-3)
        raise AssertionError("an accuracy with a tolerance accepted")
    except glissade.GlissadeError as e:
        assert e.code_name == "INVALID_ARGUMENT" and "accuracy: not with a tolerance" in e.message, e
        out["accuracy_refused"] = e.message
    try:
        c.cancel(s)
        raise AssertionError("a done study cancelled")
    except glissade.FailedPrecondition as e:
        out["failed_precondition"] = e.code_name

with glissade.Client(url, token="w" * 40) as stranger:
    try:
        stranger.studies()
        raise AssertionError("a wrong token answered")
    except glissade.Unauthenticated as e:
        out["unauthenticated"] = e.code_name

print(json.dumps(out))
