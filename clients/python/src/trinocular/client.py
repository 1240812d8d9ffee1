"""A friendly client over the generated gRPC stubs (trinocular.v1)."""

from __future__ import annotations

import json
import os
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Union

import grpc
import numpy as np
from google.protobuf import json_format

from .errors import TrinocularError, from_rpc_error
from .v1 import trinocular_pb2 as pb
from .v1 import trinocular_pb2_grpc as pb_grpc

ImageLike = Union[str, os.PathLike, bytes, bytearray, memoryview, np.ndarray, "pb.Image"]


# ---------------------------------------------------------------------------------------------
# Conversions


def _answer_may_be_lost(e: TrinocularError) -> bool:
    """A failure after which the call may or may not have been done, and a retry may succeed:
    the connection or the replica went away, the deadline passed, the service was busy, or a
    proxy reset the stream (a replica killed between a response's headers and its trailers)."""
    name = e.code.name
    return name in ("UNAVAILABLE", "DEADLINE_EXCEEDED", "RESOURCE_EXHAUSTED") or (
        name == "INTERNAL" and "RST_STREAM" in e.message)


def _to_dict(msg) -> Dict[str, Any]:
    return json_format.MessageToDict(msg)


def _stats_dict(msg) -> Dict[str, Any]:
    """Proto3 JSON of a stats message with every scalar and repeated field present (proto3
    JSON leaves out zeros, so `stats["uncertain"]` would otherwise be missing when none)."""
    out = _to_dict(msg)
    for f in msg.DESCRIPTOR.fields:
        if f.json_name in out or f.message_type is not None:
            continue
        value = getattr(msg, f.name)  # the default: 0, 0.0, False, "" or an empty container
        out[f.json_name] = value if isinstance(value, (bool, int, float, str, bytes)) else list(value)
    return out


def load_calibration(calibration) -> "pb.Calibration":
    """A Calibration message from a message, a proto3 JSON dict, a JSON string, or the path of
    a JSON file."""
    if isinstance(calibration, pb.Calibration):
        return calibration
    if isinstance(calibration, (str, os.PathLike)):
        text = str(calibration)
        if not text.lstrip().startswith("{"):
            text = Path(calibration).read_text()
        calibration = json.loads(text)
    if isinstance(calibration, dict):
        return json_format.ParseDict(calibration, pb.Calibration())
    raise TypeError(f"calibration: expected a dict, a JSON path or a Calibration, got {type(calibration)!r}")


def _parse(options, cls):
    if options is None:
        return None
    if isinstance(options, cls):
        return options
    if isinstance(options, dict):
        return json_format.ParseDict(options, cls())
    raise TypeError(f"options: expected a dict or {cls.__name__}, got {type(options)!r}")


def to_image(image: ImageLike) -> "pb.Image":
    """An Image message: a path (encoded file), bytes (encoded), or a 2-D uint8 array (raw)."""
    if isinstance(image, pb.Image):
        return image
    if isinstance(image, np.ndarray):
        if image.ndim != 2 or image.dtype != np.uint8:
            raise TypeError(
                f"image arrays must be 2-D uint8 (grey), got shape {image.shape} dtype {image.dtype}"
            )
        h, w = image.shape
        return pb.Image(raw=pb.RawImage(width=w, height=h, data=np.ascontiguousarray(image).tobytes()))
    if isinstance(image, (bytes, bytearray, memoryview)):
        return pb.Image(encoded=bytes(image))
    if isinstance(image, (str, os.PathLike)):
        return pb.Image(encoded=Path(image).read_bytes())
    raise TypeError(f"image: expected a path, bytes or a numpy array, got {type(image)!r}")


def _images(imgs: Sequence[ImageLike]) -> "pb.ImageTriplet":
    if len(imgs) != 3:
        raise ValueError(f"expected three images, got {len(imgs)}")
    return pb.ImageTriplet(images=[to_image(i) for i in imgs])


def to_segment_list(lst, oriented: bool = False) -> "pb.SegmentList":
    """A SegmentList from a message, or N×4 (u1, v1, u2, v2) / N×5 (+ gradient) / N×7
    (+ gradient, offset_sigma_px, angle_sigma_deg) / N×8 (+ shift_sigma_px) numbers; NaN:
    absent. The two sigmas (1σ of the line's position across itself at the midpoint, pixels,
    and of its direction, degrees) go together: both or neither per segment (neither: the
    server's line_noise_px model). The shift (1σ of the source's systematic shift of the
    line, pixels, independent per view) goes with them, or is absent."""
    if isinstance(lst, pb.SegmentList):
        return lst
    arr = np.asarray(lst, dtype=float)
    if arr.size == 0:
        return pb.SegmentList(oriented=oriented)
    if arr.ndim != 2 or arr.shape[1] not in (4, 5, 7, 8):
        raise ValueError(f"a segment list must be N×4, N×5, N×7 or N×8, got shape {arr.shape}")
    segs = []
    for i, row in enumerate(arr):
        s = pb.Segment(u1=row[0], v1=row[1], u2=row[2], v2=row[3])
        if arr.shape[1] >= 5 and np.isfinite(row[4]):
            s.gradient = row[4]
        if arr.shape[1] >= 7:
            known = np.isfinite(row[5:7])
            if known.all():
                s.offset_sigma_px, s.angle_sigma_deg = row[5], row[6]
            elif known.any():
                raise ValueError(
                    f"segment {i}: give both offset_sigma_px and angle_sigma_deg or neither "
                    f"(NaN), got {row[5]}, {row[6]}"
                )
        if arr.shape[1] == 8 and np.isfinite(row[7]):
            if not np.isfinite(row[5]):
                raise ValueError(
                    f"segment {i}: shift_sigma_px goes with offset_sigma_px and "
                    f"angle_sigma_deg, got {row[7]} without them"
                )
            s.shift_sigma_px = row[7]
        segs.append(s)
    return pb.SegmentList(segments=segs, oriented=oriented)


def _segments(lists, oriented: bool) -> "pb.SegmentTriplet":
    if isinstance(lists, pb.SegmentTriplet):
        return lists
    if len(lists) != 3:
        raise ValueError(f"expected three segment lists, got {len(lists)}")
    return pb.SegmentTriplet(lists=[to_segment_list(l, oriented) for l in lists])


def segment_list_array(lst: "pb.SegmentList") -> np.ndarray:
    """N×8 array (u1, v1, u2, v2, gradient, offset_sigma_px, angle_sigma_deg,
    shift_sigma_px — NaN when absent); the form `to_segment_list` takes back."""
    out = np.full((len(lst.segments), 8), np.nan)
    for i, s in enumerate(lst.segments):
        out[i, :4] = (s.u1, s.v1, s.u2, s.v2)
        if s.HasField("gradient"):
            out[i, 4] = s.gradient
        if s.HasField("offset_sigma_px"):
            out[i, 5] = s.offset_sigma_px
        if s.HasField("angle_sigma_deg"):
            out[i, 6] = s.angle_sigma_deg
        if s.HasField("shift_sigma_px"):
            out[i, 7] = s.shift_sigma_px
    return out


def _pose(matrix) -> "pb.Pose":
    """A Pose from a 4x4 (or 16 numbers, row-major), or a dict {"quaternion": [w, x, y, z],
    "translation": [x, y, z]}. A matrix printed to a few digits is accepted by the service, which
    re-orthonormalises it and says so in `CaptureResult.warnings`."""
    if isinstance(matrix, pb.Pose):
        return matrix
    if isinstance(matrix, dict):
        return pb.Pose(quaternion=[float(v) for v in matrix["quaternion"]],
                       translation=[float(v) for v in matrix["translation"]])
    m = np.asarray(matrix, dtype=float)
    if m.shape not in ((4, 4), (16,)):
        raise ValueError(f"rig_to_world must be a 4x4 matrix, got shape {m.shape}")
    return pb.Pose(matrix=m.reshape(16).tolist())


def _covariances(segments) -> np.ndarray:
    """M×6×6 from Segment3 messages' row-major `covariance` (NaN where a server sent none)."""
    out = np.full((len(segments), 6, 6), np.nan)
    for i, s in enumerate(segments):
        if len(s.covariance) == 36:
            out[i] = np.asarray(s.covariance, dtype=float).reshape(6, 6)
    return out


def _points(pairs) -> np.ndarray:
    """M×2×3 array from messages with .start and .end Point3."""
    arr = np.empty((len(pairs), 2, 3))
    for i, s in enumerate(pairs):
        arr[i, 0] = (s.start.x, s.start.y, s.start.z)
        arr[i, 1] = (s.end.x, s.end.y, s.end.z)
    return arr


# ---------------------------------------------------------------------------------------------
# Results


@dataclass
class MatchResult:
    """One capture's match. `triplets`: N×3 indices into the three input (or extracted) lists;
    `segments_3d`: M×2×3 endpoints, metres, rig frame; `residual_px`: M reprojection residuals
    of the 3D segments; `extracted`: the three extracted lists as N×8 arrays (image input with
    options {"returnExtracted": true}; see `segment_list_array`), `extracted_lists` the same as
    SegmentList messages.

    Per 3D segment: `covariance` M×6×6, of the two endpoints stacked (x1 y1 z1 x2 y2 z2),
    metres² (NaN from a server that sends none); `direction_sigma_deg` and `position_sigma_m`
    M, the 1σ of the direction (degrees) and of the midpoint across the line (metres), largest
    axis; `shift_sigma_m` M, the 1σ of the shift across the line that the three views share,
    included in `covariance` (segments of one scene compared with one another share most of it;
    see `relative_covariance`); `uncertain` M bools, True for the segments that miss the
    accuracy gate (returned only with options {"includeUncertain": true}). `stats` has every MatchStats field (zeros
    included), e.g. `stats["uncertain"]`, `stats["inconsistent"]`."""

    triplets: np.ndarray
    segments_3d: np.ndarray
    residual_px: np.ndarray
    stats: Dict[str, Any]
    triplet_residual_px: np.ndarray = None
    direction_sigma_deg: np.ndarray = None
    covariance: np.ndarray = None
    position_sigma_m: np.ndarray = None
    shift_sigma_m: np.ndarray = None
    uncertain: np.ndarray = None
    extracted: List[np.ndarray] = field(default_factory=list)
    extracted_lists: List[Any] = field(default_factory=list)
    raw: Any = None

    @classmethod
    def from_pb(cls, r: "pb.MatchResponse") -> "MatchResult":
        tri = np.array([(t.s1, t.s2, t.s3) for t in r.triplets], dtype=np.int64).reshape(-1, 3)
        segs = r.segments_3d
        return cls(
            triplets=tri,
            segments_3d=_points(segs),
            residual_px=np.array([s.residual_px for s in segs], dtype=float),
            stats=_stats_dict(r.stats),
            triplet_residual_px=np.array([t.residual_px for t in r.triplets], dtype=float),
            direction_sigma_deg=np.array([s.direction_sigma_deg for s in segs], dtype=float),
            covariance=_covariances(segs),
            position_sigma_m=np.array([s.position_sigma_m for s in segs], dtype=float),
            shift_sigma_m=np.array([s.shift_sigma_m for s in segs], dtype=float),
            uncertain=np.array([s.uncertain for s in segs], dtype=bool),
            extracted=[segment_list_array(l) for l in r.extracted],
            extracted_lists=list(r.extracted),
            raw=r,
        )

    def _across(self):
        """Per segment: P = I - u uᵀ (M×3×3, u the unit direction) and the length L (M)."""
        d = self.segments_3d[:, 1] - self.segments_3d[:, 0]
        length = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        u = d / length[:, None]
        return np.eye(3) - u[:, :, None] * u[:, None, :], length

    def _propagate(self, j: np.ndarray) -> np.ndarray:
        return j @ self.covariance @ np.swapaxes(j, 1, 2)

    def direction_covariance(self) -> np.ndarray:
        """M×3×3 covariance of each segment's unit direction u = (end - start) / L, radians²:
        J C Jᵀ with J = [-P/L, P/L], P = I - u uᵀ (rank 2, across the line; the square root
        of its largest eigenvalue is `direction_sigma_deg`, in radians)."""
        p, length = self._across()
        p = p / length[:, None, None]
        return self._propagate(np.concatenate([-p, p], axis=2))

    def midpoint_covariance(self) -> np.ndarray:
        """M×3×3 covariance of each segment's midpoint across the line, metres²: J C Jᵀ with
        J = [P/2, P/2] (rank 2; the square root of its largest eigenvalue is
        `position_sigma_m`). Along the line the endpoints' spread is not Gaussian and is left
        out."""
        p, _ = self._across()
        return self._propagate(np.concatenate([p / 2, p / 2], axis=2))

    def relative_covariance(self) -> np.ndarray:
        """M×6×6 `covariance` without the shift the three views share (σ² P in each 3×3
        block, P = I - u uᵀ, σ = `shift_sigma_m`): what two segments of one scene are compared
        by, as a session's registration and fusion do."""
        p, _ = self._across()
        block = p * (self.shift_sigma_m ** 2)[:, None, None]
        return self.covariance - np.block([[block, block], [block, block]])


@dataclass
class Map:
    """A session's fused map, world frame: `segments` M×2×3, `observations` M captures
    counts, `captures` per-segment capture indices, `poses` K×4×4 rig poses (solved by the
    pose graph unless the session's `refine_poses` is false), `prior_poses` K×4×4 as given;
    per segment its fused `covariances` M×6×6 (start, end; m², world frame, the poses'
    uncertainty included), `direction_sigma_deg` and `position_sigma_m` (M), and
    `uncertain` (M, true only where the session's options include uncertain segments)."""

    session_id: str
    segments: np.ndarray
    observations: np.ndarray
    captures: List[List[int]]
    poses: np.ndarray
    fuse_ms: float = 0.0
    raw: Any = None
    prior_poses: Optional[np.ndarray] = None
    covariances: Optional[np.ndarray] = None
    direction_sigma_deg: Optional[np.ndarray] = None
    position_sigma_m: Optional[np.ndarray] = None
    uncertain: Optional[np.ndarray] = None

    @classmethod
    def from_pb(cls, m: "pb.Map") -> "Map":
        def covariance(s):
            c = list(s.covariance)
            return np.array(c, dtype=float).reshape(6, 6) if len(c) == 36 else np.full((6, 6), np.nan)

        return cls(
            session_id=m.session_id,
            segments=_points(m.segments),
            observations=np.array([s.observations for s in m.segments], dtype=np.int64),
            captures=[list(s.captures) for s in m.segments],
            poses=np.array([list(p.matrix) for p in m.poses], dtype=float).reshape(-1, 4, 4),
            fuse_ms=m.fuse_ms,
            raw=m,
            prior_poses=np.array([list(p.matrix) for p in m.prior_poses],
                                 dtype=float).reshape(-1, 4, 4),
            covariances=np.array([covariance(s) for s in m.segments], dtype=float).reshape(-1, 6, 6),
            direction_sigma_deg=np.array([s.direction_sigma_deg for s in m.segments], dtype=float),
            position_sigma_m=np.array([s.position_sigma_m for s in m.segments], dtype=float),
            uncertain=np.array([s.uncertain for s in m.segments], dtype=bool),
        )

    def summary(self) -> str:
        if len(self.segments) == 0:
            return f"map {self.session_id}: 0 segments, {len(self.poses)} poses"
        lengths = np.linalg.norm(self.segments[:, 1] - self.segments[:, 0], axis=1)
        multi = int((self.observations >= 2).sum())
        return (
            f"map {self.session_id}: {len(self.segments)} segments ({multi} seen by 2+ captures), "
            f"total length {lengths.sum():.2f} m, {len(self.poses)} poses, fused in {self.fuse_ms:.1f} ms"
        )


@dataclass
class Session:
    id: str
    name: str
    created_unix_ms: int
    last_used_unix_ms: int
    captures: int
    idle_ttl_s: int
    calibration: Optional[Dict[str, Any]] = None
    options: Optional[Dict[str, Any]] = None
    map_options: Optional[Dict[str, Any]] = None
    raw: Any = None

    @classmethod
    def from_pb(cls, s: "pb.Session") -> "Session":
        return cls(
            id=s.id,
            name=s.name,
            created_unix_ms=s.created_unix_ms,
            last_used_unix_ms=s.last_used_unix_ms,
            captures=s.captures,
            idle_ttl_s=s.idle_ttl_s,
            calibration=_to_dict(s.calibration) if s.HasField("calibration") else None,
            options=_to_dict(s.options) if s.HasField("options") else None,
            map_options=_to_dict(s.map_options) if s.HasField("map_options") else None,
            raw=s,
        )


@dataclass
class CaptureResult:
    """AddCapture's answer: this capture's match (rig frame), its index, the capture count,
    and its registration to the map: `status` ("REGISTERED", "EMPTY_MAP",
    "TOO_FEW_IN_COMMON", "DISAGREES_WITH_PRIOR"), `rig_to_world` (4x4, refined, or as given with
    its heading turned by the room's directions), `covariance` (6x6),
    `inliers`, `rotation_change_deg`, `translation_change_m`. `duplicate`: the capture's
    name (`capture_id`) was one the session held already — a retry, answered with that
    capture's index and registration, nothing stored again."""

    capture_index: int
    captures: int
    match: MatchResult
    registration: Optional[Dict[str, Any]] = None
    # What the service accepted with a correction (a near-rigid pose re-orthonormalised).
    warnings: List[str] = field(default_factory=list)
    duplicate: bool = False


@dataclass
class CalibrationResult:
    """`calibration`: proto3 JSON dict usable as the `calibration` of every call; `reports`:
    per camera {camera, rmsPx, maxPx, points, boardsFound}."""

    calibration: Dict[str, Any]
    reports: List[Dict[str, Any]]
    total_ms: float = 0.0
    raw: Any = None


# ---------------------------------------------------------------------------------------------
# Client


class Client:
    """A connection to a Trinocular server's gRPC port.

    >>> c = Client("localhost:50051")
    >>> r = c.match_images("demo/calibration.json", "demo/img1.png", "demo/img2.png", "demo/img3.png")
    >>> r.segments_3d.shape  # (M, 2, 3)
    """

    def __init__(self, target: str = "localhost:50051", timeout: Optional[float] = None,
                 max_message_mib: int = 64, channel: Optional[grpc.Channel] = None,
                 api_key: Optional[str] = None, tls: bool = False,
                 ca_cert: Union[str, Path, bytes, None] = None, retries: int = 0):
        """`api_key`: sent as `authorization: Bearer <key>` on every call, for a service
        started with API keys (its sessions are then this key's own).

        `retries`: how many times a call that is safe to repeat is sent again after a failure
        that may have lost its answer (UNAVAILABLE, DEADLINE_EXCEEDED, RESOURCE_EXHAUSTED, a
        reset stream), with backoff: matching, calibration, reading sessions and maps,
        CreateSession and AddCapture (given a UUID for it, unless `session_id` or
        `capture_id` is given: made or stored once). DeleteSession is not repeated (a repeat
        would say NOT_FOUND).

        `tls=True`: the server serves TLS (`--tls-cert`/`--tls-key`) and its certificate is
        trusted by the system; `ca_cert` (a PEM file's path, or its bytes): trust this
        certificate (a private CA or a self-signed server certificate) instead, which implies
        TLS. `target`'s host must be a name the certificate carries."""
        if retries < 0:
            raise ValueError("retries must be 0 or more")
        self.target = target
        self.timeout = timeout
        self.retries = retries
        self._metadata = [("authorization", f"Bearer {api_key}")] if api_key else None
        n = max_message_mib * 1024 * 1024
        options = [("grpc.max_send_message_length", n), ("grpc.max_receive_message_length", n)]
        if channel is not None:
            self._channel = channel
        elif tls or ca_cert is not None:
            if isinstance(ca_cert, (str, Path)):
                ca_cert = Path(ca_cert).read_bytes()
            credentials = grpc.ssl_channel_credentials(root_certificates=ca_cert)
            self._channel = grpc.secure_channel(target, credentials, options=options)
        else:
            self._channel = grpc.insecure_channel(target, options=options)
        self._stub = pb_grpc.TrinocularStub(self._channel)

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _retried(self, retries: Optional[int], name: Optional[str]):
        """The retries of a call that makes something (the client's by default), and the name
        that makes repeating it safe: `name`, or a random UUID when it is to be retried."""
        retries = self.retries if retries is None else retries
        if retries < 0:
            raise ValueError("retries must be 0 or more")
        if name is None and retries > 0:
            name = uuid.uuid4().hex
        return retries, name

    def _call_again(self, name: str, request, default_field: Optional[str] = None,
                    retries: Optional[int] = None):
        """`_call`, sent again up to `retries` (default: the client's) times while its answer
        may have been lost. Only for calls that are safe to repeat."""
        retries = self.retries if retries is None else retries
        for attempt in range(retries + 1):
            try:
                return self._call(name, request, default_field)
            except TrinocularError as e:
                if attempt == retries or not _answer_may_be_lost(e):
                    raise
                time.sleep(min(2.0, 0.2 * 2 ** attempt))

    def _call(self, name: str, request, default_field: Optional[str] = None):
        try:
            return getattr(self._stub, name)(request, timeout=self.timeout,
                                             metadata=self._metadata)
        except grpc.RpcError as e:
            raise from_rpc_error(e, default_field) from None

    # -- matching ------------------------------------------------------------------------------

    def match_images(self, calibration, img1: ImageLike, img2: ImageLike, img3: ImageLike,
                     options=None) -> MatchResult:
        """Extracts segments from three images and matches them. Images: paths, encoded bytes,
        or 2-D uint8 numpy arrays. `options`: MatchOptions as proto3 JSON dict (camelCase or
        snake_case names, e.g. {"includeUncertain": True, "gatePositionM": 0.05}) or message."""
        req = pb.MatchRequest(calibration=load_calibration(calibration),
                              images=_images([img1, img2, img3]))
        opts = _parse(options, pb.MatchOptions)
        if opts is not None:
            req.options.CopyFrom(opts)
        return MatchResult.from_pb(self._call_again("Match", req))

    def match_segments(self, calibration, lists, options=None, oriented: bool = False) -> MatchResult:
        """Matches three segment lists (each N×4 (u1, v1, u2, v2), N×5 with gradient, N×7
        with gradient, offset_sigma_px and angle_sigma_deg, N×8 with shift_sigma_px too, or a
        SegmentList; NaN: absent);
        `oriented`: the lists are oriented by contrast. `MatchResult.extracted` of an image
        match can be passed back with oriented=True."""
        req = pb.MatchRequest(calibration=load_calibration(calibration),
                              segments=_segments(lists, oriented))
        opts = _parse(options, pb.MatchOptions)
        if opts is not None:
            req.options.CopyFrom(opts)
        return MatchResult.from_pb(self._call_again("Match", req))

    # -- calibration ---------------------------------------------------------------------------

    def calibrate(self, img1: ImageLike, img2: ImageLike, img3: ImageLike, pattern=None,
                  distortion: bool = False, pattern_to_rig=None,
                  camera_names: Optional[Sequence[str]] = None, extract=None,
                  rig_from_pattern=None) -> CalibrationResult:
        """Estimates the three cameras from images of the pattern (default: the README's).
        `pattern_to_rig` (4x4) puts the calibration in the rig frame; `rig_from_pattern` is its
        former name, still accepted."""
        if rig_from_pattern is not None:
            if pattern_to_rig is not None:
                raise ValueError("give pattern_to_rig only (rig_from_pattern is its former name)")
            pattern_to_rig = rig_from_pattern
        req = pb.CalibrateRequest(images=_images([img1, img2, img3]))
        pat = _parse(pattern, pb.CalibrationPattern)
        if pat is not None:
            req.pattern.CopyFrom(pat)
        if pattern_to_rig is not None:
            req.pattern_to_rig.CopyFrom(_pose(pattern_to_rig))
        req.options.distortion = bool(distortion)
        ext = _parse(extract, pb.ExtractOptions)
        if ext is not None:
            req.options.extract.CopyFrom(ext)
        if camera_names:
            req.camera_names.extend(camera_names)
        r = self._call_again("Calibrate", req)
        return CalibrationResult(
            calibration=_to_dict(r.calibration),
            reports=[_to_dict(x) for x in r.reports],
            total_ms=r.total_ms,
            raw=r,
        )

    def import_calibration(self, format: str, files: Sequence[Union[str, os.PathLike]]) -> Dict[str, Any]:
        """A calibration (proto3 JSON dict, as `match_images` takes it) from other tools' files:
        `format` "kalibr" (camchain.yaml), "opencv-yaml" / "opencv-xml" (FileStorage) or "ros"
        (three CameraInfo YAML files, cameras 1, 2, 3). `files`: paths, or the files' text."""
        texts = []
        for f in files:
            text = str(f)
            if isinstance(f, os.PathLike) or ("\n" not in text and Path(text).is_file()):
                text = Path(f).read_text()
            texts.append(text)
        r = self._call_again("ImportCalibration", pb.ImportCalibrationRequest(format=format, files=texts))
        return _to_dict(r)

    def export_calibration(self, format: str, calibration) -> List[str]:
        """`calibration` written as other tools' files (one, or three for "ros"); the
        extrinsics relative to camera 1."""
        req = pb.ExportCalibrationRequest(format=format, calibration=load_calibration(calibration))
        return list(self._call_again("ExportCalibration", req).files)

    # -- sessions ------------------------------------------------------------------------------

    def create_session(self, calibration, name: str = "", options=None,
                       min_observations: Optional[int] = None,
                       refine_poses: Optional[bool] = None, session_id: Optional[str] = None,
                       retries: Optional[int] = None) -> Session:
        """`refine_poses` (default true): GetMap solves every capture's pose from the poses
        given and what each capture's segments said, when it was added, about the captures it
        overlaps (a pose graph: docs/SESSIONS.md); false fuses with the poses as given, taken
        as exact.

        `session_id` (letters, digits and '-', up to 64) names the session: sent again, a
        create whose answer was lost is answered with the session as it stands, not made
        twice; the id of another session is `AlreadyExists`. `retries` (default: the
        client's): how many times to send it again after a failure that may have lost the
        answer — the session is then given a random id unless `session_id` is."""
        retries, session_id = self._retried(retries, session_id)
        req = pb.CreateSessionRequest(name=name, calibration=load_calibration(calibration),
                                      session_id=session_id or "")
        opts = _parse(options, pb.MatchOptions)
        if opts is not None:
            req.options.CopyFrom(opts)
        if min_observations is not None:
            req.map_options.min_observations = int(min_observations)
        if refine_poses is not None:
            req.map_options.refine_poses = bool(refine_poses)
        if not session_id:
            return Session.from_pb(self._call("CreateSession", req))
        return Session.from_pb(self._call_again("CreateSession", req, "session_id", retries))

    def add_capture(self, session_id: str, rig_to_world, images: Optional[Sequence[ImageLike]] = None,
                    segments=None, oriented: bool = False,
                    rig_to_world_covariance=None, capture_id: Optional[str] = None,
                    retries: Optional[int] = None) -> CaptureResult:
        """Adds one capture taken from `rig_to_world` (4x4, the robot's belief: a prior the
        capture is registered from): `images` (three) or `segments` (three lists), not both.
        `rig_to_world_covariance`: 6x6 (rotation about the rig's origin, radians, then
        translation, metres); None for a wheeled robot's default.

        `capture_id` names the capture (unique in the session, 1-128 printable ASCII, no
        spaces): sent again under its name, a capture whose answer was lost is answered, not
        stored twice (`CaptureResult.duplicate`). `retries` (default: the client's): how many
        times to send it again after a failure that may have lost the answer (UNAVAILABLE,
        DEADLINE_EXCEEDED, RESOURCE_EXHAUSTED, a reset stream), with backoff; the capture is
        then named with a random UUID unless `capture_id` is given. A caller that retries by
        calling again gives the same `capture_id` itself."""
        if (images is None) == (segments is None):
            raise ValueError("give exactly one of images= or segments=")
        retries, capture_id = self._retried(retries, capture_id)
        req = pb.AddCaptureRequest(session_id=session_id, rig_to_world=_pose(rig_to_world),
                                   capture_id=capture_id or "")
        if rig_to_world_covariance is not None:
            c = np.asarray(rig_to_world_covariance, dtype=float).reshape(-1)
            req.rig_to_world_covariance.extend(c.tolist())
        if images is not None:
            req.images.CopyFrom(_images(list(images)))
        else:
            req.segments.CopyFrom(_segments(segments, oriented))
        r = self._call_again("AddCapture", req, "session_id", retries)
        g = r.registration
        registration = {
            "status": pb.RegistrationStatus.Name(g.status),
            "rig_to_world": np.array(list(g.rig_to_world.matrix), dtype=float).reshape(4, 4),
            "covariance": np.array(list(g.covariance), dtype=float).reshape(6, 6),
            "inliers": g.inliers,
            "rotation_change_deg": g.rotation_change_deg,
            "translation_change_m": g.translation_change_m,
        }
        return CaptureResult(capture_index=r.capture_index, captures=r.map.captures,
                             match=MatchResult.from_pb(r.match), registration=registration,
                             warnings=list(r.warnings), duplicate=r.duplicate)

    def get_map(self, session_id: str, min_observations: Optional[int] = None) -> Map:
        req = pb.GetMapRequest(session_id=session_id)
        if min_observations is not None:
            req.min_observations = int(min_observations)
        return Map.from_pb(self._call_again("GetMap", req, "session_id"))

    def get_session(self, session_id: str) -> Session:
        return Session.from_pb(self._call_again("GetSession", pb.GetSessionRequest(session_id=session_id),
                                          "session_id"))

    def list_sessions(self) -> List[Session]:
        """Every session of this key (the service answers a page at a time)."""
        sessions, token = [], ""
        while True:
            r = self._call_again("ListSessions", pb.ListSessionsRequest(page_size=1000, page_token=token))
            sessions.extend(Session.from_pb(s) for s in r.sessions)
            if not r.next_page_token:
                return sessions
            token = r.next_page_token

    def delete_session(self, session_id: str) -> None:
        self._call("DeleteSession", pb.DeleteSessionRequest(session_id=session_id), "session_id")
