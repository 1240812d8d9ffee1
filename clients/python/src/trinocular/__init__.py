"""Python client for the Trinocular trinocular-stereo service."""

from .client import (
    CalibrationResult,
    CaptureResult,
    Client,
    Map,
    MatchResult,
    Session,
    load_calibration,
)
from .errors import (
    AlreadyExists,
    DeadlineExceeded,
    InvalidArgument,
    NotFound,
    ResourceExhausted,
    TrinocularError,
    Unavailable,
)

__all__ = [
    "Client", "MatchResult", "Map", "Session", "CaptureResult", "CalibrationResult",
    "load_calibration", "TrinocularError", "InvalidArgument", "NotFound", "Unavailable",
    "ResourceExhausted", "DeadlineExceeded", "AlreadyExists",
]
__version__ = "0.1.0"
