"""The glissade coordinator's user API (proto/proto/glissade.proto, service User) for Python."""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field
from typing import Any, Dict, Iterator, List, Mapping, Optional, Sequence, Union

import grpc
import numpy as np
import pandas as pd

from . import errors
from ._scene import read_scene
from .proto import glissade_pb2 as pb
from .proto import glissade_pb2_grpc as pb_grpc

DEFAULT_URL = "http://127.0.0.1:50051"

#: A study: its id, or anything with a `study_id` (a Submitted, a Study message).
StudyRef = Union[int, Any]
#: One grid axis: "START:STOP:COUNT", "V1,V2,...", "lhs:N:SEED", or the values themselves.
GridSpec = Union[str, Sequence[float]]


def _study_id(study: StudyRef) -> int:
    sid = getattr(study, "study_id", study)
    if isinstance(sid, bool) or not isinstance(sid, (int, np.integer)):
        raise TypeError(f"a study is an id or has a study_id, got {study!r}")
    return int(sid)


def _number(v: float) -> str:
    """A value as the coordinator parses it, exactly (repr round-trips a float)."""
    return repr(float(v))


def _scientific(v: float, decimals: int) -> str:
    """As Rust's `{:.N e}`: "2.946e-5", not Python's "2.946e-05"."""
    mantissa, exponent = f"{v:.{decimals}e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def qoi_text(value: float, digits: int, resolution: float = 0.0) -> str:
    """A QoI's value as the CLI and the web page write it (core::text::qoi_value, the one rule):
    `digits` significant digits ("2.946e-5"), exactly "0" below its `resolution` (a stuck slip's
    round-off). A surface frame's attrs carry both: frame.attrs["digits"], frame.attrs["resolutions"]."""
    v = float(value)
    if math.isnan(v):
        return "NaN"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    if v == 0.0 or abs(v) < resolution:
        return "0"
    return _scientific(v, max(1, min(17, digits)) - 1)


def _grid_specs(grid: Mapping[str, GridSpec]) -> List[str]:
    specs = []
    for name, spec in grid.items():
        if isinstance(spec, str):
            specs.append(f"{name}={spec}")
        else:
            specs.append(f"{name}=" + ",".join(_number(v) for v in spec))
    return specs


def _range_specs(ranges: Mapping[str, Union[str, Sequence[float]]]) -> List[str]:
    specs = []
    for name, box in ranges.items():
        if isinstance(box, str):
            specs.append(f"{name}={box}")
        else:
            low, high = box
            specs.append(f"{name}={_number(low)}:{_number(high)}")
    return specs


def read_token(token_file: Optional[str] = None) -> Optional[str]:
    """The user token as the CLI finds it: the file given, else GLISSADE_TOKEN, else the file
    GLISSADE_TOKEN_FILE names, else none."""
    if token_file is None and "GLISSADE_TOKEN" in os.environ:
        return os.environ["GLISSADE_TOKEN"].strip()
    token_file = token_file or os.environ.get("GLISSADE_TOKEN_FILE")
    if token_file is None:
        return None
    try:
        with open(token_file, encoding="ascii") as f:
            return f.read().strip()
    except OSError as e:
        raise errors.GlissadeError(f"cannot read token file {token_file}: {e.strerror}") from e


@dataclass(frozen=True)
class Submitted:
    """What SubmitStudy answered: the study's id, its number of points, the scene's hash."""

    study_id: int
    points: int
    scene_hash: str

    def __int__(self) -> int:
        return self.study_id

    __index__ = __int__


@dataclass(frozen=True)
class Event:
    """One event of a study's progress (WatchStudy).

    `kind`: "snapshot", "point_started", "point_finished", "point_failed", "point_requeued",
    "point_progress" or "study_ended"; `state`: the study's, "active", "done", "failed" or
    "cancelled"; `point`: the PointStatus concerned (None for snapshot and study_ended);
    `replay`: the event replays the state at the start of the stream.
    """

    kind: str
    study_id: int
    state: str
    done: int
    failed: int
    total: int
    replay: bool
    point: Optional[Any]
    parameters: Dict[str, float] = field(default_factory=dict)
    qoi: Dict[str, float] = field(default_factory=dict)
    raw: Optional[Any] = field(default=None, repr=False)


@dataclass(frozen=True)
class Prediction:
    """A QoI predicted by the response surface: its mean, one standard deviation, the number
    of points the surface was fitted to, and its band of 2 standard deviations (low, high),
    within the bound the physics sets (a slip's norm: never below zero)."""

    mean: float
    std: float
    fitted_points: int
    low: float = math.nan
    high: float = math.nan
    digits: int = 6

    def __str__(self) -> str:
        # as `glissade surface --at` prints it
        return f"{qoi_text(self.mean, self.digits)} +- {_scientific(self.std, 2)}"


@dataclass(frozen=True)
class SurfaceArrays:
    """A response surface as arrays: x[i, j] is parameter j at point i, y[i, k] QoI k there
    (NaN where the point has none, e.g. not done)."""

    parameters: List[str]
    qoi: List[str]
    x: np.ndarray
    y: np.ndarray


def _enum_name(enum, value: int, prefix: str) -> str:
    """An enum value's short name ("done"); a value this package does not know (a newer
    coordinator's) is "unknown_<n>", not an exception."""
    try:
        return enum.Name(value).removeprefix(prefix).lower()
    except ValueError:
        return f"unknown_{value}"


def _state_name(value: int) -> str:
    return _enum_name(pb.StudyState, value, "STUDY_STATE_")


# The coordinator stores solution files of at most 4 GiB (glissade-server --max-solution-bytes):
# a stream that says more, or sends more than it said, is refused before it fills the memory.
MAX_SOLUTION_BYTES = 4 << 30


class Client:
    """A connection to a glissade coordinator.

    `url`: http://host:port or https://host:port (default $GLISSADE_SERVER, else
    http://127.0.0.1:50051). `token`: the user token (default as the CLI: token_file, else
    $GLISSADE_TOKEN, else the file $GLISSADE_TOKEN_FILE names), sent as
    `authorization: Bearer <token>`. `ca_cert`: PEM file (or bytes) of the authority that signed
    an https coordinator's certificate (default $GLISSADE_CA_CERT, else the system's roots);
    giving one makes the connection TLS. `timeout`: seconds for each call but watch.

    Every refused call raises glissade.GlissadeError with the gRPC status code and message.
    """

    def __init__(
        self,
        url: Optional[str] = None,
        token: Optional[str] = None,
        ca_cert: Union[str, bytes, None] = None,
        token_file: Optional[str] = None,
        timeout: float = 30.0,
    ):
        url = url or os.environ.get("GLISSADE_SERVER") or DEFAULT_URL
        self.url = url
        self.timeout = timeout
        token = token if token is not None else read_token(token_file)
        self._metadata = (("authorization", f"Bearer {token}"),) if token else ()
        if ca_cert is None and url.startswith("https://"):
            ca_cert = os.environ.get("GLISSADE_CA_CERT")
        target = url.removeprefix("https://").removeprefix("http://").rstrip("/")
        if url.startswith("https://") or ca_cert is not None:
            if isinstance(ca_cert, str):
                try:
                    with open(ca_cert, "rb") as f:
                        ca_cert = f.read()
                except OSError as e:
                    raise errors.GlissadeError(f"cannot read the CA certificate {ca_cert}: {e.strerror}") from e
            self._channel = grpc.secure_channel(target, grpc.ssl_channel_credentials(ca_cert))
        else:
            self._channel = grpc.insecure_channel(target)
        self._user = pb_grpc.UserStub(self._channel)
        self._health = pb_grpc.HealthStub(self._channel)

    # -- plumbing ---------------------------------------------------------------------------

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _call(self, method, request, timeout: Optional[float] = None):
        try:
            return method(request, timeout=timeout or self.timeout, metadata=self._metadata)
        except grpc.RpcError as e:
            raise errors.from_rpc(e) from None

    def _stream(self, method, request, timeout: Optional[float]) -> Iterator[Any]:
        call = method(request, timeout=timeout, metadata=self._metadata)
        try:
            yield from call
        except grpc.RpcError as e:
            raise errors.from_rpc(e) from None
        finally:
            call.cancel()  # a caller that stops iterating early ends the stream (no-op when done)

    # -- the API ----------------------------------------------------------------------------

    def health(self) -> Dict[str, str]:
        """The coordinator's status ("SERVING") and version."""
        reply = self._call(self._health.Check, pb.HealthRequest())
        return {"status": reply.status, "version": reply.version, "detail": reply.detail}

    def submit(
        self,
        scene: str,
        grid: Optional[Mapping[str, GridSpec]] = None,
        *,
        points: Optional[Sequence[Mapping[str, float]]] = None,
        ranges: Optional[Mapping[str, Union[str, Sequence[float]]]] = None,
        adaptive: Optional[int] = None,
        tol: Optional[float] = None,
        max_iterations: Optional[int] = None,
        strategy: Optional[str] = None,
        order: Optional[str] = None,
        neighbours: int = 0,
        label: str = "",
        audit: Optional[int] = None,
        refine: Optional[int] = None,
        refine_levels: int = 0,
        surface_audit: Optional[int] = None,
        accuracy: Optional[float] = None,
        pilots: Optional[int] = None,
    ) -> Submitted:
        """Submits a study of the scene file `scene` (its mesh files, next to it, travel with it).

        One of: `grid` {name: "0.1:0.2:11" | "0.1,0.15" | [0.1, 0.15]} (the product of the
        axes), `points` [{name: value}, ...], or `adaptive`=N with `ranges` {name: (low, high)}.
        `tol`: tolerance on eta (default the scene's); `strategy`: "cold", "previous",
        "nearest", "blend" or "linear" (default the coordinator's); `order`: "ascending",
        "descending" or "greedy"; `audit`, `refine`, `surface_audit`: points of the audits
        (None: the coordinator's default, 0: none), as `glissade submit --help` says.
        `accuracy`: solve the study to this accuracy (0.05: every QoI within 5 % of its scale),
        its `pilots` (default 3) choosing dt, h and the tolerance first; the study's
        `to_accuracy` then says what they chose (docs/accuracy.md, "A study to an accuracy").
        """
        given = [x for x in (grid, points, adaptive) if x is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of grid=, points= or adaptive= (with ranges=)")
        if (adaptive is None) != (ranges is None):
            raise ValueError("adaptive= and ranges= go together")
        text, meshes = read_scene(os.fspath(scene))
        request = pb.SubmitStudyRequest(
            scene=text,
            grid=_grid_specs(grid) if grid is not None else [],
            points=[pb.ParameterVector(values={k: float(v) for k, v in p.items()}) for p in points or []],
            ranges=_range_specs(ranges) if ranges is not None else [],
            adaptive_points=adaptive or 0,
            strategy=pb.InitStrategy.Value("INIT_STRATEGY_" + (strategy or "unspecified").upper()),
            order=pb.PointOrder.Value("POINT_ORDER_" + (order or "unspecified").upper()),
            blend_neighbours=neighbours,
            label=label,
            refine_levels=refine_levels,
            meshes=[pb.MeshFile(file=name, data=data, sha256=digest) for name, data, digest in meshes],
        )
        for name, value in [
            ("tolerance", tol),
            ("max_iterations", max_iterations),
            ("audit_points", audit),
            ("refine_points", refine),
            ("surface_audit_points", surface_audit),
            ("accuracy", accuracy),
            ("accuracy_pilots", pilots),
        ]:
            if value is not None:
                setattr(request, name, value)
        reply = self._call(self._user.SubmitStudy, request, timeout=max(self.timeout, 120.0))
        return Submitted(reply.study_id, reply.points, reply.scene_hash)

    def study(self, study: StudyRef, points: bool = False, scene: bool = False):
        """The study (a glissade.pb.Study message), with every point's status if `points`."""
        return self._call(self._user.GetStudy, pb.GetStudyRequest(study_id=_study_id(study), points=points, scene=scene))

    def state(self, study: StudyRef) -> str:
        """The study's state as the CLI names it: "active", "done", "cancelled"..."""
        return _state_name(self.study(study).state)

    def audits(self, study: StudyRef) -> List[Dict[str, Any]]:
        """The study's audits and pilot levels, one dict each (as `glissade show` lists them):
        study_id, what ("iteration", "time step", "mesh", "surface", "held-out check", "pilot
        level"), state ("active", "done", "cancelled"), done, total, failed, cancelled, and
        why_cancelled (why some points were cancelled unsolved, or None)."""
        return [
            {
                "study_id": a.study_id,
                "what": a.what,
                "state": _state_name(a.state),
                "done": a.progress.done,
                "total": a.progress.total,
                "failed": a.progress.failed,
                "cancelled": a.progress.cancelled,
                "why_cancelled": a.why_cancelled or None,
            }
            for a in self.study(study).audits
        ]

    def verdicts(self, study: StudyRef) -> List[str]:
        """Which error dominates each QoI, one sentence a QoI, as `glissade show` and the web page
        say it: the iterations' error the study's audit measured beside the time step's and the
        mesh's its discretisation audit estimated (empty until it has two of them)."""
        return list(self.study(study).verdicts)

    def studies(self) -> list:
        """Every study (Study messages without their points), newest last, fetched page by page."""
        studies, after = [], 0
        while True:
            page = self._call(self._user.ListStudies, pb.ListStudiesRequest(after=after))
            studies.extend(page.studies)
            if page.next_after == 0 or page.next_after <= after:
                return studies
            after = page.next_after

    def cancel(self, study: StudyRef):
        """Stops handing out the study's points; the Study after it."""
        return self._call(self._user.CancelStudy, pb.CancelStudyRequest(study_id=_study_id(study)))

    def watch(self, study: StudyRef, timeout: Optional[float] = None) -> Iterator[Event]:
        """The study's events until it is no longer active: first a snapshot and the replayed
        state, then every change as it happens. `timeout`: give up (DEADLINE_EXCEEDED) after
        this many seconds (default: never)."""
        request = pb.WatchStudyRequest(study_id=_study_id(study))
        for e in self._stream(self._user.WatchStudy, request, timeout):
            point = e.point if e.HasField("point") else None
            yield Event(
                kind=_enum_name(pb.EventKind, e.kind, "EVENT_KIND_"),
                study_id=e.study_id,
                state=_state_name(e.state),
                done=e.progress.done,
                failed=e.progress.failed,
                total=e.progress.total,
                replay=e.replay,
                point=point,
                parameters=dict(sorted(point.parameters.items())) if point is not None else {},
                qoi=dict(sorted(point.qoi.items())) if point is not None else {},
                raw=e,
            )

    def wait(self, study: StudyRef, timeout: Optional[float] = None):
        """Follows the study until it ends; the Study (with its points) then."""
        for _ in self.watch(study, timeout=timeout):
            pass
        return self.study(study, points=True)

    def _surface(self, study, scene_hash, qoi, fixed, predict_at=()):
        if (study is None) == (scene_hash is None):
            raise ValueError("give a study or scene_hash=, not both")
        qoi = [qoi] if isinstance(qoi, str) else list(qoi or [])
        request = pb.QuerySurfaceRequest(
            qoi=qoi,
            fixed={k: float(v) for k, v in (fixed or {}).items()},
            predict_at=[pb.ParameterPoint(parameters=p) for p in predict_at],
        )
        if study is not None:
            request.study_id = _study_id(study)
        else:
            request.scene_hash = scene_hash
        return self._call(self._user.QuerySurface, request)

    def surface(
        self,
        study: Optional[StudyRef] = None,
        qoi: Union[str, Sequence[str], None] = None,
        fixed: Optional[Mapping[str, float]] = None,
        scene_hash: Optional[str] = None,
        exact: bool = False,
    ) -> pd.DataFrame:
        """The response surface: one row per point, columns the parameters, the QoIs (all, or
        those named; NaN where a point has none), then iterations, error_indicator, converged,
        state. `fixed` {name: value} keeps a slice; `scene_hash` instead of a study: every
        stored solution of that scene. `frame.attrs["units"]`: each QoI's unit and each
        parameter's that declares one ("m", "m/s", "N"). A QoI below what the solves resolve
        (a stuck slip's round-off, `frame.attrs["resolutions"]`) is 0.0, as the CLI and the web
        page show it, unless `exact`; `qoi_text(v, frame.attrs["digits"])` writes a value as they do."""
        reply = self._surface(study, scene_hash, qoi, fixed)
        columns = list(reply.parameters) + list(reply.qoi)
        resolutions = dict(reply.resolutions)

        def shown(q: str, v: float) -> float:
            return 0.0 if not exact and abs(v) < resolutions.get(q, 0.0) else v

        rows = [
            [p.parameters.get(n, math.nan) for n in reply.parameters]
            + [shown(q, p.qoi[q]) if q in p.qoi else math.nan for q in reply.qoi]
            # a point that failed before its first iteration has no indicator (sent as the largest double)
            + [p.iterations, p.error_indicator if p.error_indicator < sys.float_info.max else math.nan, p.converged,
               _enum_name(pb.PointState, p.state, "POINT_STATE_")]
            for p in reply.points
        ]
        frame = pd.DataFrame(rows, columns=columns + ["iterations", "error_indicator", "converged", "state"])
        frame.attrs.update(scene_hash=reply.scene_hash, parameters=list(reply.parameters), qoi=list(reply.qoi),
                           units=dict(reply.units), resolutions=resolutions, digits=reply.digits or 6)
        return frame

    def surface_arrays(
        self,
        study: Optional[StudyRef] = None,
        qoi: Union[str, Sequence[str], None] = None,
        fixed: Optional[Mapping[str, float]] = None,
        scene_hash: Optional[str] = None,
    ) -> SurfaceArrays:
        """The response surface as numpy arrays (x: points by parameters, y: points by QoIs)."""
        frame = self.surface(study, qoi=qoi, fixed=fixed, scene_hash=scene_hash)
        names, qois = frame.attrs["parameters"], frame.attrs["qoi"]
        return SurfaceArrays(
            names, qois, frame[names].to_numpy(dtype=float).reshape(len(frame), len(names)),
            frame[qois].to_numpy(dtype=float).reshape(len(frame), len(qois)),
        )

    def predict(
        self,
        study: StudyRef,
        at: Union[Mapping[str, float], Sequence[Mapping[str, float]], pd.DataFrame],
        qoi: Union[str, Sequence[str], None] = None,
        fixed: Optional[Mapping[str, float]] = None,
    ):
        """The response surface's prediction (a Gaussian process per QoI) between the points.

        `at` one point {name: value} (every parameter of the surface): a Prediction(mean, std,
        fitted_points) when `qoi` is one name, else {qoi: Prediction}. `at` several points (a
        list of dicts or a DataFrame of parameter columns): a DataFrame with the parameters
        and, per QoI, columns `q` (the mean), `q_std`, and `q_low`, `q_high` (the band of 2 sd,
        within the physics' bound: a norm's never below zero).
        """
        one = isinstance(at, Mapping)
        if isinstance(at, pd.DataFrame):
            points = at.to_dict("records")
        else:
            points = [at] if one else list(at)
        points = [{k: float(v) for k, v in p.items()} for p in points]
        reply = self._surface(study, None, qoi, fixed, points)
        if len(reply.predictions) != len(points):
            raise errors.GlissadeError(
                f"the coordinator answered {len(reply.predictions)} predictions for {len(points)} points")
        if one:
            found = {
                q: Prediction(v.mean, v.std, v.fitted_points, v.low, v.high, reply.digits or 6)
                for q, v in reply.predictions[0].qoi.items()
            }
            if isinstance(qoi, str):
                if qoi not in found:
                    raise errors.GlissadeError(f"no prediction of {qoi} (the surface has {sorted(found)})")
                return found[qoi]
            return found
        qois = sorted({q for p in reply.predictions for q in p.qoi})
        rows = []
        for point, p in zip(points, reply.predictions):
            row = dict(point)
            for q in qois:
                v = p.qoi.get(q)
                row[q] = v.mean if v is not None else math.nan
                row[f"{q}_std"] = v.std if v is not None else math.nan
                row[f"{q}_low"] = v.low if v is not None else math.nan
                row[f"{q}_high"] = v.high if v is not None else math.nan
            rows.append(row)
        frame = pd.DataFrame(rows)
        frame.attrs["units"] = dict(reply.units)
        return frame

    def fetch_solution(
        self,
        study: Optional[StudyRef] = None,
        point: Optional[int] = None,
        *,
        at: Optional[Mapping[str, float]] = None,
        scene_hash: Optional[str] = None,
        parameters: Optional[Mapping[str, float]] = None,
        path: Optional[str] = None,
    ) -> Union[bytes, str]:
        """The bytes of a stored solution file (docs/solution-format.md): of `point` (its id) of
        `study`, or of the study's point at the swept parameters `at`, or the stored solution of
        `scene_hash` at every scene parameter `parameters`. With `path`, writes them there and
        returns the path."""
        if scene_hash is not None:
            request = pb.FetchSolutionRequest(key=pb.SolutionKey(scene_hash=scene_hash, parameters=parameters or {}))
        else:
            if study is None or (point is None) == (at is None):
                raise ValueError("give study= with point= or at=, or scene_hash= with parameters=")
            if at is not None:
                point = self._point_at(study, at)
            request = pb.FetchSolutionRequest(point=pb.PointKey(study_id=_study_id(study), point_id=point))
        data = bytearray()
        total = None
        for chunk in self._stream(self._user.FetchSolution, request, max(self.timeout, 300.0)):
            if chunk.offset != len(data):
                raise errors.GlissadeError(f"solution stream: chunk at {chunk.offset}, expected {len(data)}")
            if total is not None and chunk.total_bytes != total:
                raise errors.GlissadeError(f"solution stream: its size changed from {total} to {chunk.total_bytes} bytes")
            total = chunk.total_bytes
            if total > MAX_SOLUTION_BYTES or len(data) + len(chunk.data) > total:
                raise errors.GlissadeError(
                    f"solution stream: {len(data) + len(chunk.data)} bytes of a file said to hold {total} "
                    f"(at most {MAX_SOLUTION_BYTES})")
            data += chunk.data
        if total is not None and len(data) != total:
            raise errors.GlissadeError(f"solution stream ended at {len(data)} of {total} bytes")
        if path is None:
            return bytes(data)
        with open(path, "wb") as f:
            f.write(data)
        return path

    def _point_at(self, study: StudyRef, at: Mapping[str, float]) -> int:
        for p in self.study(study, points=True).points:
            if all(k in p.parameters and math.isclose(p.parameters[k], float(v), rel_tol=1e-9, abs_tol=1e-300)
                   for k, v in at.items()):
                return p.point_id
        raise errors.NotFound(f"study {_study_id(study)} has no point at {dict(at)}", grpc.StatusCode.NOT_FOUND)
