"""glissade: the coordinator's API for Python.

    import glissade
    with glissade.Client("http://127.0.0.1:50051") as c:
        s = c.submit("scenes/three-blocks-tiny.toml", grid={"f1": "0.1:0.2:3", "f2": [0.1, 0.2]}, tol=1e-3)
        for e in c.watch(s):
            print(e.kind, e.done, e.total)
        frame = c.surface(s, qoi="slip_A")             # a pandas DataFrame
        p = c.predict(s, at={"f1": 0.13, "f2": 0.17}, qoi="slip_A")   # p.mean, p.std

Messages are those of proto/proto/glissade.proto (glissade.pb); errors are GlissadeError with
the gRPC status code.
"""

from .client import Client, Event, Prediction, Submitted, SurfaceArrays, qoi_text, read_token
from .errors import (
    FailedPrecondition,
    GlissadeError,
    InvalidArgument,
    NotFound,
    PermissionDenied,
    Unauthenticated,
    Unavailable,
)
from .proto import glissade_pb2 as pb
from .proto import glissade_pb2_grpc as pb_grpc

__version__ = "0.3.0"

__all__ = [
    "Client",
    "Event",
    "FailedPrecondition",
    "GlissadeError",
    "InvalidArgument",
    "NotFound",
    "PermissionDenied",
    "Prediction",
    "Submitted",
    "SurfaceArrays",
    "Unauthenticated",
    "Unavailable",
    "pb",
    "pb_grpc",
    "qoi_text",
    "read_token",
]
