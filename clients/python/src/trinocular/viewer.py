"""Send a match or a session's map to the Rerun viewer (https://rerun.io).

`rerun-sdk` is an optional dependency (``pip install 'trinocular[rerun]'``); this module
imports it only when called. Entity paths, under a prefix (``match`` or ``session`` by default):

- a match: ``{prefix}/world/segments_3d`` (LineStrips3D, rig frame, each 3D segment in its
  colour of the overlay), ``{prefix}/world/cameras`` (the optical centres, Points3D, when the
  calibration is given), ``{prefix}/images/{camera}`` (the image, when given) and
  ``{prefix}/images/{camera}/segments`` (the extracted segments, LineStrips2D: matched ones in
  their 3D segment's colour, the others grey — options ``{"returnExtracted": true}``);
- a map: ``{prefix}/world/map`` (LineStrips3D, world frame, light blue seen once to dark red
  seen most, as the PLY export), ``{prefix}/world/rig/{k}`` (each capture's pose the map uses,
  Transform3D), ``{prefix}/world/poses`` and ``{prefix}/world/poses_given`` (Points3D, blue
  and orange) and ``{prefix}/world/headings`` (Arrows3D, where each rig looked).

Everything is logged as static data. Typical use::

    import rerun as rr
    from trinocular.viewer import log_match
    rr.init("trinocular", spawn=True)          # or rec = rr.RecordingStream(...); rec.save(path)
    log_match(result, images=paths, calibration="calibration.json")
"""

from __future__ import annotations

import colorsys
import os
from typing import Optional, Sequence

import numpy as np

from .client import Map, MatchResult, load_calibration

UNMATCHED = (150, 150, 150)
POSE = (31, 95, 208)
PRIOR = (230, 120, 20)


def _rr():
    try:
        import rerun
    except ImportError as e:  # pragma: no cover - the message is the point
        raise ImportError(
            "trinocular.viewer needs rerun-sdk: pip install 'trinocular[rerun]' (or rerun-sdk)"
        ) from e
    return rerun


def colour(i: int):
    """The overlay's colour for 3D segment `i` (golden-angle hues), as the service draws it."""
    hue = (i * 137.507764) % 360.0
    r, g, b = colorsys.hsv_to_rgb(hue / 360.0, 0.9, 1.0)
    return tuple(int(round(255 * c)) for c in (r, g, b))


def observation_colour(observations: int, most: int):
    """The PLY export's colour of a map segment seen `observations` times out of `most`."""
    f = (observations - 1) / (most - 1) if most > 1 else 1.0
    mix = lambda a, b: int(round(a + (b - a) * f))  # noqa: E731
    return (mix(120, 180), mix(170, 20), mix(230, 30))


def _projections(calibration):
    cal = load_calibration(calibration)
    out = []
    for camera in cal.cameras:
        p = np.array(list(camera.projection), dtype=float)
        if p.size != 12:
            k = np.array(list(camera.intrinsics), dtype=float).reshape(3, 3)
            r = np.array(list(camera.rotation), dtype=float).reshape(3, 3)
            t = np.array(list(camera.translation), dtype=float).reshape(3, 1)
            p = k @ np.hstack([r, t])
        out.append(p.reshape(3, 4))
    return out


def camera_centres(calibration) -> np.ndarray:
    """3×3: each camera's optical centre in the rig frame (the null vector of its P)."""
    return np.array([-np.linalg.solve(p[:, :3], p[:, 3]) for p in _projections(calibration)])


def rig_marker(calibration):
    """Where a rig's cameras are (their centroid) and where they look (their mean optical
    axis, unit), in the rig frame: what the service's top views draw at each pose."""
    axes = []
    for p in _projections(calibration):
        m = p[:, :3]
        axes.append(np.sign(np.linalg.det(m)) * m[2] / np.linalg.norm(m[2]))
    look = np.sum(axes, axis=0)
    return camera_centres(calibration).mean(axis=0), look / max(np.linalg.norm(look), 1e-12)


def _owners(result: MatchResult):
    """Per view, {index of the extracted segment: index of the 3D segment it went into}."""
    owners = [{}, {}, {}]
    for k, s in enumerate(result.raw.segments_3d if result.raw is not None else []):
        for t in (list(s.triplets) or [s.triplet]):
            if t < len(result.triplets):
                for v in range(3):
                    owners[v][int(result.triplets[t][v])] = k
    return owners


def log_match(result: MatchResult, images: Optional[Sequence] = None, calibration=None,
              prefix: str = "match", recording=None) -> None:
    """Logs one match: its 3D segments, the cameras, and (when given) the images with their
    extracted segments. `images`: three paths (PNG/JPEG, logged as encoded) or 2-D uint8
    arrays; `calibration`: as `Client.match_images` takes it (names the cameras and places
    them). `recording`: a `rerun.RecordingStream`, or the global one."""
    rr = _rr()
    log = recording.log if recording is not None else rr.log
    n = len(result.segments_3d)
    log(f"{prefix}/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    log(f"{prefix}/world/segments_3d",
        rr.LineStrips3D(result.segments_3d.astype(np.float32), colors=[colour(k) for k in range(n)],
                        radii=rr.Radius.ui_points(2.0)),
        static=True)
    names = ["cam1", "cam2", "cam3"]
    if calibration is not None:
        cal = load_calibration(calibration)
        names = [c.name or f"cam{v + 1}" for v, c in enumerate(cal.cameras)]
        log(f"{prefix}/world/cameras",
            rr.Points3D(camera_centres(cal).astype(np.float32), colors=[POSE] * 3,
                        labels=names, radii=rr.Radius.ui_points(6.0)),
            static=True)
    owners = _owners(result)
    for v in range(3):
        path = f"{prefix}/images/{names[v]}"
        if images is not None:
            image = images[v]
            if isinstance(image, np.ndarray):
                log(path, rr.Image(image), static=True)
            else:
                log(path, rr.EncodedImage(path=os.fspath(image)), static=True)
        if v < len(result.extracted) and len(result.extracted[v]):
            ends = result.extracted[v][:, :4].reshape(-1, 2, 2).astype(np.float32)
            # Pixel centres are at integer coordinates; Rerun's at half-integers.
            colours = [colour(owners[v][i]) if i in owners[v] else UNMATCHED
                       for i in range(len(ends))]
            log(f"{path}/segments", rr.LineStrips2D(ends + 0.5, colors=colours), static=True)


def log_map(m: Map, calibration=None, prefix: str = "session", recording=None) -> None:
    """Logs a session's map: its segments coloured by observations, each capture's pose (the
    map's and, in orange, as given) and heading. With the session's `calibration` the rigs are
    drawn where their cameras were, looking where they looked; without, at the rig frame's
    origin looking along its +y axis."""
    rr = _rr()
    log = recording.log if recording is not None else rr.log
    log(f"{prefix}/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    most = int(m.observations.max()) if len(m.observations) else 1
    log(f"{prefix}/world/map",
        rr.LineStrips3D(m.segments.astype(np.float32),
                        colors=[observation_colour(int(o), most) for o in m.observations],
                        radii=rr.Radius.ui_points(2.0)),
        static=True)
    for k, pose in enumerate(m.poses):
        log(f"{prefix}/world/rig/{k}",
            rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]), static=True)
    centre, look = rig_marker(calibration) if calibration is not None else (np.zeros(3), np.array([0.0, 1.0, 0.0]))
    place = lambda poses: (poses[:, :3, :3] @ centre + poses[:, :3, 3]).astype(np.float32).reshape(-1, 3)  # noqa: E731
    positions = place(m.poses)
    log(f"{prefix}/world/poses",
        rr.Points3D(positions, colors=[POSE] * len(positions), radii=rr.Radius.ui_points(6.0),
                    labels=[str(k) for k in range(len(positions))]),
        static=True)
    if m.prior_poses is not None and len(m.prior_poses):
        given = place(m.prior_poses)
        log(f"{prefix}/world/poses_given",
            rr.Points3D(given, colors=[PRIOR] * len(given), radii=rr.Radius.ui_points(4.0)),
            static=True)
    headings = (m.poses[:, :3, :3] @ (0.3 * look)).astype(np.float32).reshape(-1, 3)
    log(f"{prefix}/world/headings",
        rr.Arrows3D(origins=positions, vectors=headings, colors=[POSE] * len(positions)),
        static=True)
