"""Exceptions raised by the client: one per gRPC status code the service uses."""

from __future__ import annotations

import re
from typing import Optional

import grpc

# Input errors read "calibration.cameras[2].projection: needs exactly 12 numbers".
_FIELD = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*(?:\[\d+\])*(?:\.[A-Za-z_][A-Za-z0-9_]*(?:\[\d+\])*)*): ")


class TrinocularError(Exception):
    """A failed call. `code` is a grpc.StatusCode, `message` the server's text, `field` the
    offending request field (e.g. "calibration.cameras[2].projection") when known."""

    def __init__(self, code: grpc.StatusCode, message: str, field: Optional[str] = None):
        super().__init__(f"{code.name}: {message}")
        self.code = code
        self.message = message
        self.field = field


class InvalidArgument(TrinocularError):
    pass


class NotFound(TrinocularError):
    pass


class Unavailable(TrinocularError):
    pass


class ResourceExhausted(TrinocularError):
    pass


class AlreadyExists(TrinocularError):
    """A session id or capture name the client chose names another session or capture."""


class DeadlineExceeded(TrinocularError):
    pass


_BY_CODE = {
    grpc.StatusCode.INVALID_ARGUMENT: InvalidArgument,
    grpc.StatusCode.NOT_FOUND: NotFound,
    grpc.StatusCode.UNAVAILABLE: Unavailable,
    grpc.StatusCode.RESOURCE_EXHAUSTED: ResourceExhausted,
    grpc.StatusCode.ALREADY_EXISTS: AlreadyExists,
    grpc.StatusCode.DEADLINE_EXCEEDED: DeadlineExceeded,
}


def parse_field(message: str) -> Optional[str]:
    """The field named by a message's "field: ..." prefix, or None."""
    m = _FIELD.match(message or "")
    return m.group(1) if m else None


def from_rpc_error(e: grpc.RpcError, default_field: Optional[str] = None) -> TrinocularError:
    code = e.code() if hasattr(e, "code") else grpc.StatusCode.UNKNOWN
    message = (e.details() if hasattr(e, "details") else None) or code.name.lower().replace("_", " ")
    named = (grpc.StatusCode.INVALID_ARGUMENT, grpc.StatusCode.ALREADY_EXISTS)
    field = parse_field(message) if code in named else None
    if field is None and code == grpc.StatusCode.NOT_FOUND:
        field = default_field
    cls = _BY_CODE.get(code, TrinocularError)
    return cls(code, message, field)
