"""Errors of the glissade client: every refused call raises GlissadeError (or a subclass)."""

from __future__ import annotations

from typing import Optional

import grpc


class GlissadeError(Exception):
    """A call the coordinator refused or could not answer.

    `code` is the gRPC status (grpc.StatusCode.NOT_FOUND, ...), `code_name` its name
    ("NOT_FOUND"), `message` the coordinator's one line naming the offending field or object.
    Errors found before any call (a scene file that cannot be read) have code None.
    """

    def __init__(self, message: str, code: Optional[grpc.StatusCode] = None):
        super().__init__(f"{message} ({code.name})" if code is not None else message)
        self.message = message
        self.code = code

    @property
    def code_name(self) -> Optional[str]:
        return self.code.name if self.code is not None else None


class InvalidArgument(GlissadeError):
    """A malformed request: scene text, grid, parameter out of range (INVALID_ARGUMENT)."""


class NotFound(GlissadeError):
    """An unknown study, point or solution (NOT_FOUND)."""


class FailedPrecondition(GlissadeError):
    """A valid request the study's state forbids, e.g. cancelling a finished study."""


class Unauthenticated(GlissadeError):
    """No user token, or the wrong one (UNAUTHENTICATED)."""


class PermissionDenied(GlissadeError):
    """A token of another role, e.g. a pool's token on the user service (PERMISSION_DENIED)."""


class Unavailable(GlissadeError):
    """The coordinator cannot be reached, or is shutting down (UNAVAILABLE): retry later."""


_BY_CODE = {
    grpc.StatusCode.INVALID_ARGUMENT: InvalidArgument,
    grpc.StatusCode.NOT_FOUND: NotFound,
    grpc.StatusCode.FAILED_PRECONDITION: FailedPrecondition,
    grpc.StatusCode.UNAUTHENTICATED: Unauthenticated,
    grpc.StatusCode.PERMISSION_DENIED: PermissionDenied,
    grpc.StatusCode.UNAVAILABLE: Unavailable,
}


def from_rpc(error: grpc.RpcError) -> GlissadeError:
    """The GlissadeError of a failed call (its status code and details)."""
    code = error.code() if hasattr(error, "code") else grpc.StatusCode.UNKNOWN
    details = error.details() if hasattr(error, "details") else str(error)
    return _BY_CODE.get(code, GlissadeError)(details or str(code), code)
