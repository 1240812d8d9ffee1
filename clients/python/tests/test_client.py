"""The client against a live server: $TRINOCULAR_BIN (default <repo>/target/release/trinocular)."""

import contextlib
import json
import os
import re
import subprocess
import threading
from pathlib import Path

import grpc
import numpy as np
import pytest

import trinocular
from trinocular import AlreadyExists, Client, InvalidArgument, NotFound, TrinocularError

REPO = Path(__file__).resolve().parents[3]
IDENTITY = np.eye(4)


def _binary() -> Path:
    b = Path(os.environ.get("TRINOCULAR_BIN", REPO / "target" / "release" / "trinocular"))
    if not b.is_file():
        pytest.fail(f"no server binary at {b}: run `cargo build --release` or set TRINOCULAR_BIN")
    return b


@contextlib.contextmanager
def _serve(*extra_args, env=None):
    """`trinocular serve` on ephemeral ports with `extra_args`; yields (grpc_addr, http_addr)."""
    proc = subprocess.Popen(
        [str(_binary()), "serve", "--grpc-addr", "127.0.0.1:0", "--http-addr", "127.0.0.1:0",
         "--store", "memory", "--threads", "2", *extra_args],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        env={**os.environ, **(env or {})},
    )
    found = {}
    ready = threading.Event()
    log = []

    def read():
        for line in proc.stderr:
            log.append(line)
            m = re.search(r"listening.*grpc=(\S+) http=(\S+)", re.sub(r"\x1b\[[0-9;]*m", "", line))
            if m and not ready.is_set():
                found["grpc"], found["http"] = m.group(1), m.group(2)
                ready.set()

    threading.Thread(target=read, daemon=True).start()
    try:
        if not ready.wait(30):
            pytest.fail("server did not report `listening`:\n" + "".join(log))
        yield found["grpc"], found["http"]
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="session")
def server():
    """The plain-TCP server most tests share; yields (grpc_addr, http_addr)."""
    with _serve() as addrs:
        yield addrs


@pytest.fixture(scope="session")
def client(server):
    with Client(server[0], timeout=60) as c:
        yield c


@pytest.fixture(scope="session")
def demo(tmp_path_factory):
    """`trinocular demo --out DIR`: img1..3.png and calibration.json."""
    out = tmp_path_factory.mktemp("demo")
    subprocess.run([str(_binary()), "demo", "--out", str(out)], check=True,
                   stdout=subprocess.DEVNULL)
    return out


def _grey(path: Path) -> np.ndarray:
    """A PNG decoded to a 2-D uint8 array by the server itself is not available, so decode it
    with the standard library (8-bit grey or RGB, non-interlaced PNG)."""
    import struct
    import zlib

    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, w = 8, b"", 0
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, colour = struct.unpack(">IIBB", body[:10])
            assert depth == 8 and colour in (0, 2, 4, 6), (depth, colour)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    channels = {0: 1, 2: 3, 4: 2, 6: 4}[colour]
    raw = zlib.decompress(idat)
    stride = w * channels
    out = np.zeros((h, stride), dtype=np.int32)
    prev = np.zeros(stride, dtype=np.int32)
    for y in range(h):
        f = raw[y * (stride + 1)]
        line = np.frombuffer(raw, np.uint8, stride, y * (stride + 1) + 1).astype(np.int32)
        if f == 0:
            cur = line.copy()
        elif f == 2:
            cur = (line + prev) & 0xFF
        elif f == 1:
            cur = (np.cumsum(line.reshape(-1, channels), axis=0) & 0xFF).reshape(-1)
        else:
            cur = np.zeros(stride, dtype=np.int32)
            for x in range(stride):
                a = cur[x - channels] if x >= channels else 0
                b = prev[x]
                c = prev[x - channels] if x >= channels else 0
                if f == 3:
                    p = (a + b) // 2
                else:
                    pa, pb_, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                    p = a if pa <= pb_ and pa <= pc else (b if pb_ <= pc else c)
                cur[x] = (line[x] + p) & 0xFF
        out[y] = cur
        prev = cur
    img = out.reshape(h, w, channels)
    if channels == 1:
        return img[:, :, 0].astype(np.uint8)
    return img[:, :, 0].astype(np.uint8) if channels == 2 else np.round(
        img[:, :, :3] @ [0.299, 0.587, 0.114]).astype(np.uint8)


def _paths(demo):
    return [demo / f"img{i}.png" for i in (1, 2, 3)]


def test_match_images_paths_bytes_arrays_agree(client, demo):
    cal = demo / "calibration.json"
    by_path = client.match_images(cal, *_paths(demo))
    assert by_path.segments_3d.ndim == 3 and by_path.segments_3d.shape[1:] == (2, 3)
    assert len(by_path.segments_3d) > 10
    assert by_path.triplets.shape[1] == 3 and by_path.triplets.dtype.kind == "i"
    assert by_path.stats["triplets"] == len(by_path.triplets)
    by_bytes = client.match_images(json.loads(cal.read_text()),
                                   *[p.read_bytes() for p in _paths(demo)])
    np.testing.assert_array_equal(by_path.segments_3d, by_bytes.segments_3d)
    np.testing.assert_array_equal(by_path.triplets, by_bytes.triplets)


def test_match_images_numpy_raw(client, demo):
    cal = demo / "calibration.json"
    arrays = [_grey(p) for p in _paths(demo)]
    if any(a.ndim != 2 for a in arrays):  # pragma: no cover
        pytest.skip("unexpected PNG layout")
    by_path = client.match_images(cal, *_paths(demo))
    by_array = client.match_images(cal, *arrays)
    # Grey PNGs decode to the same pixels; colour ones may differ by rounding of the grey.
    if all(_is_grey_png(p) for p in _paths(demo)):
        np.testing.assert_array_equal(by_path.segments_3d, by_array.segments_3d)
    else:
        assert abs(len(by_array.segments_3d) - len(by_path.segments_3d)) <= 0.1 * len(by_path.segments_3d) + 2


def _is_grey_png(p: Path) -> bool:
    return p.read_bytes()[25] == 0


def test_match_segments_from_extracted(client, demo):
    cal = demo / "calibration.json"
    images = client.match_images(cal, *_paths(demo), options={"returnExtracted": True})
    assert len(images.extracted) == 3 and all(e.shape[1] == 8 for e in images.extracted)
    # extracted segments carry their measured line sigmas (columns 5, 6), both or neither, and
    # the extractor's shift with them (column 7)
    for e in images.extracted:
        assert np.array_equal(np.isfinite(e[:, 5]), np.isfinite(e[:, 6]))
        assert np.array_equal(np.isfinite(e[:, 5]), np.isfinite(e[:, 7]))
        assert np.isfinite(e[:, 5]).any() and (e[np.isfinite(e[:, 5]), 5:] > 0).all()
    oriented = all(l.oriented for l in images.extracted_lists)
    segs = client.match_segments(cal, images.extracted, oriented=oriented)
    np.testing.assert_allclose(segs.segments_3d, images.segments_3d)
    np.testing.assert_array_equal(segs.triplets, images.triplets)
    # plain (u1, v1, u2, v2) lists work too
    plain = client.match_segments(cal, [e[:, :4].tolist() for e in images.extracted])
    assert len(plain.segments_3d) > 0


def _assert_covariances(r):
    m = len(r.segments_3d)
    assert r.covariance.shape == (m, 6, 6)
    assert r.position_sigma_m.shape == (m,) and r.uncertain.shape == (m,)
    assert r.uncertain.dtype == bool
    assert np.isfinite(r.covariance).all()
    scale = np.abs(r.covariance).max(axis=(1, 2))
    assert (scale > 0).all()
    np.testing.assert_allclose(r.covariance, np.swapaxes(r.covariance, 1, 2),
                               rtol=0, atol=1e-12 * scale.max())
    eig = np.linalg.eigvalsh(r.covariance)
    assert (eig >= -1e-12 * eig.max(axis=1, keepdims=True)).all(), eig.min()
    # The helpers' Jacobians agree with the server's own sigmas.
    d, p = r.direction_covariance(), r.midpoint_covariance()
    assert d.shape == (m, 3, 3) and p.shape == (m, 3, 3)
    np.testing.assert_allclose(np.degrees(np.sqrt(np.linalg.eigvalsh(d)[:, -1])),
                               r.direction_sigma_deg, rtol=1e-6)
    np.testing.assert_allclose(np.sqrt(np.linalg.eigvalsh(p)[:, -1]), r.position_sigma_m,
                               rtol=1e-6)
    # Both are across the line: the direction is in their null space.
    u = r.segments_3d[:, 1] - r.segments_3d[:, 0]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    for c in (d, p):
        assert (np.linalg.norm(c @ u[:, :, None], axis=(1, 2))
                <= 1e-9 * np.abs(c).max(axis=(1, 2))).all()
    # The shift the views share is in the covariance: taken out, the direction is the same and
    # the midpoint is σ² narrower across the line.
    assert r.shift_sigma_m.shape == (m,) and (r.shift_sigma_m > 0).all()
    relative = r.relative_covariance()
    j_dir = np.concatenate([-np.eye(3), np.eye(3)], axis=1)
    np.testing.assert_allclose(j_dir @ relative @ j_dir.T, j_dir @ r.covariance @ j_dir.T,
                               rtol=0, atol=1e-12 * scale.max())
    across = np.eye(3) - u[:, :, None] * u[:, None, :]
    np.testing.assert_allclose(p - across @ (relative[:, :3, :3] + relative[:, :3, 3:]
                                             + relative[:, 3:, :3] + relative[:, 3:, 3:]) @ across / 4,
                               across * (r.shift_sigma_m ** 2)[:, None, None],
                               rtol=0, atol=1e-12 * scale.max())


def test_covariances_and_uncertain(client, demo):
    cal = demo / "calibration.json"
    default = client.match_images(cal, *_paths(demo))
    assert len(default.segments_3d) > 10
    _assert_covariances(default)
    assert not default.uncertain.any()
    for key in ("uncertain", "inconsistent"):
        assert isinstance(default.stats[key], int) and default.stats[key] >= 0
    everything = client.match_images(cal, *_paths(demo), options={"includeUncertain": True})
    _assert_covariances(everything)
    assert len(everything.segments_3d) >= len(default.segments_3d)
    assert int(everything.uncertain.sum()) == everything.stats["uncertain"]
    assert len(everything.segments_3d) - len(default.segments_3d) == default.stats["uncertain"]
    # the certain ones are the default answer
    np.testing.assert_allclose(everything.segments_3d[~everything.uncertain], default.segments_3d)
    # lists that state no noise: the model's, each view's own shift in what is reported
    images = client.match_images(cal, *_paths(demo), options={"returnExtracted": True})
    plain = client.match_segments(cal, [e[:, :5] for e in images.extracted],
                                  options={"includeUncertain": True})
    assert len(plain.segments_3d) > 10
    _assert_covariances(plain)


def test_gate_options(client, demo):
    cal = demo / "calibration.json"
    n = len(client.match_images(cal, *_paths(demo), options={"include_uncertain": True}).segments_3d)
    # a position tolerance of a nanometre: every segment misses the gate
    strict = {"gatePositionM": 1e-9, "gatePositionRel": 0.0}
    none = client.match_images(cal, *_paths(demo), options=strict)
    assert len(none.segments_3d) == 0 and none.stats["uncertain"] == n
    flagged = client.match_images(cal, *_paths(demo), options={**strict, "include_uncertain": True})
    assert len(flagged.segments_3d) == n and flagged.uncertain.all()
    # a gate as loose as can be lets through at least the default answer
    loose = {"gateDirectionDeg": 90.0, "gatePositionM": 1e3, "gateConfidence": 0.01}
    assert len(client.match_images(cal, *_paths(demo), options=loose).segments_3d) >= \
        len(client.match_images(cal, *_paths(demo)).segments_3d)
    # out-of-range gates are refused, naming the option
    with pytest.raises(InvalidArgument) as e:
        client.match_images(cal, *_paths(demo), options={"gatePositionM": 0.0})
    assert e.value.field == "options.gate_position_m", e.value.message


def test_segment_sigmas(client, demo):
    cal = demo / "calibration.json"
    images = client.match_images(cal, *_paths(demo), options={"returnExtracted": True})
    oriented = all(l.oriented for l in images.extracted_lists)
    opts = {"includeUncertain": True}
    base = client.match_segments(cal, images.extracted, options=opts, oriented=oriented)
    noisier = [e.copy() for e in images.extracted]
    for e in noisier:
        e[:, 5:7] *= 10
    loose = client.match_segments(cal, noisier, options=opts, oriented=oriented)
    assert len(base.segments_3d) > 0 and len(loose.segments_3d) > 0
    assert np.median(loose.position_sigma_m) > 3 * np.median(base.position_sigma_m)
    # only one of the pair: refused by the client
    half = [e.copy() for e in images.extracted]
    half[1][np.flatnonzero(np.isfinite(half[1][:, 6]))[0], 6] = np.nan
    with pytest.raises(ValueError, match="both"):
        client.match_segments(cal, half, oriented=oriented)
    # a shift without the sigmas: refused by the client; out of range: by the server, named
    lone = [e.copy() for e in images.extracted]
    lone[0][0, 5:7] = np.nan
    with pytest.raises(ValueError, match="shift_sigma_px"):
        client.match_segments(cal, lone, oriented=oriented)
    far = [e.copy() for e in images.extracted]
    far[2][np.flatnonzero(np.isfinite(far[2][:, 7]))[0], 7] = 2.0
    with pytest.raises(InvalidArgument) as e:
        client.match_segments(cal, far, oriented=oriented)
    assert e.value.field.endswith(".shift_sigma_px") and e.value.field.startswith(
        "segments.lists[2]"), e.value.field
    # a shift stated widens what is reported, not what is matched
    shifted = [e.copy() for e in images.extracted]
    for e in shifted:
        e[:, 7] = np.where(np.isfinite(e[:, 7]), 0.5, np.nan)
    wider = client.match_segments(cal, shifted, options=opts, oriented=oriented)
    np.testing.assert_array_equal(wider.triplets, base.triplets)
    assert np.median(wider.position_sigma_m) > np.median(base.position_sigma_m)


def test_invalid_calibration_names_the_field(client, demo):
    cal = json.loads((demo / "calibration.json").read_text())
    cam = cal["cameras"][2]
    for k in ("intrinsics", "rotation", "translation"):
        cam.pop(k, None)
    cam["projection"] = [1.0, 2.0, 3.0]
    with pytest.raises(InvalidArgument) as e:
        client.match_images(cal, *_paths(demo))
    assert e.value.field == "calibration.cameras[2].projection", e.value.message
    assert isinstance(e.value, TrinocularError)


def test_session_lifecycle(client, demo):
    cal = demo / "calibration.json"
    s = client.create_session(cal, name="py-test", min_observations=1)
    assert re.fullmatch(r"[0-9a-f]{32}", s.id) and s.name == "py-test"
    once = None
    for i in range(2):
        if i == 1:
            once = client.get_map(s.id)
        r = client.add_capture(s.id, IDENTITY, images=_paths(demo))
        assert r.capture_index == i and r.captures == i + 1
        assert len(r.match.segments_3d) > 0
        # The first capture anchors the map; the second, the same view again, registers to it
        # where it was.
        assert r.registration["status"] == ("EMPTY_MAP", "REGISTERED")[i]
        assert r.registration["covariance"].shape == (6, 6)
        assert r.registration["translation_change_m"] < 0.01
    m = client.get_map(s.id)
    assert m.segments.shape[1:] == (2, 3) and len(m.segments) > 0
    assert m.poses.shape == (2, 4, 4)
    np.testing.assert_array_equal(m.prior_poses[0], IDENTITY)
    np.testing.assert_array_equal(m.poses[0], IDENTITY)
    assert m.observations.max() == 2
    # Each map segment carries its fused covariance; seen twice, an edge is known better than
    # once (information adds: σ shrinks by about √2).
    assert m.covariances.shape == (len(m.segments), 6, 6)
    assert np.all(m.position_sigma_m > 0) and not m.uncertain.any()
    assert np.median(m.position_sigma_m) < np.median(once.position_sigma_m) / 1.2
    assert len(client.get_map(s.id, min_observations=3).segments) == 0
    assert client.get_session(s.id).captures == 2
    assert s.id in [x.id for x in client.list_sessions()]
    client.delete_session(s.id)
    with pytest.raises(NotFound) as e:
        client.get_session(s.id)
    assert e.value.field == "session_id"
    with pytest.raises(NotFound):
        client.get_map(s.id)


def test_a_named_capture_sent_again_is_answered_not_stored(client, demo, monkeypatch):
    s = client.create_session(demo / "calibration.json", name="retries")
    first = client.add_capture(s.id, IDENTITY, images=_paths(demo), capture_id="robot-1/0001")
    again = client.add_capture(s.id, IDENTITY, images=_paths(demo), capture_id="robot-1/0001")
    assert not first.duplicate and again.duplicate
    assert again.capture_index == first.capture_index == 0
    np.testing.assert_array_equal(again.registration["rig_to_world"],
                                  first.registration["rig_to_world"])
    assert client.get_session(s.id).captures == 1
    # The name of a capture the session holds, with another pose: refused, naming it.
    moved = IDENTITY.copy()
    moved[0, 3] = 0.1
    with pytest.raises(AlreadyExists) as e:
        client.add_capture(s.id, moved, images=_paths(demo), capture_id="robot-1/0001")
    assert e.value.field == "capture_id", e.value.message

    # With retries, an answer lost in transport is asked for again under the same name.
    sent, call = [], client._call

    def lossy(name, request, default_field=None):
        sent.append(request.capture_id)
        answer = call(name, request, default_field)
        if len(sent) == 1:
            raise TrinocularError(grpc.StatusCode.UNAVAILABLE, "connection reset")
        return answer

    monkeypatch.setattr(client, "_call", lossy)
    r = client.add_capture(s.id, moved, images=_paths(demo), retries=2)
    monkeypatch.undo()
    assert len(sent) == 2 and sent[0] == sent[1] and re.fullmatch(r"[0-9a-f]{32}", sent[0])
    assert r.duplicate and r.capture_index == 1
    assert client.get_session(s.id).captures == 2
    client.delete_session(s.id)


def test_a_client_with_retries_repeats_only_what_is_safe_to_repeat(server, demo, monkeypatch):
    with Client(server[0], timeout=60, retries=2) as c:
        sent, lost, call = [], set(), c._call

        def lossy(name, request, default_field=None):
            # The first answer of each call is lost on the way back: the call was made.
            sent.append(name)
            answer = call(name, request, default_field)
            if name not in lost and name in ("Match", "CreateSession"):
                lost.add(name)
                raise TrinocularError(grpc.StatusCode.UNAVAILABLE, "connection reset")
            return answer

        monkeypatch.setattr(c, "_call", lossy)
        r = c.match_images(demo / "calibration.json", *_paths(demo))
        assert len(r.segments_3d) > 0 and sent == ["Match", "Match"]
        # A create is repeated under the id the client gave it: one session, not two.
        s = c.create_session(demo / "calibration.json", name="retried")
        assert sent[2:] == ["CreateSession", "CreateSession"]
        assert re.fullmatch(r"[0-9a-f]{32}", s.id)
        assert [x.id for x in c.list_sessions()].count(s.id) == 1
        again = c.create_session(demo / "calibration.json", name="retried", session_id=s.id)
        assert again.id == s.id and again.created_unix_ms == s.created_unix_ms
        with pytest.raises(AlreadyExists) as e:
            c.create_session(demo / "calibration.json", name="another", session_id=s.id)
        assert e.value.field == "session_id", e.value.message
        c.delete_session(s.id)
        # Nor is an answer that was not lost.
        bad = json.loads((demo / "calibration.json").read_text())
        bad["cameras"][2]["projection"] = [1.0, 2.0, 3.0]
        for k in ("intrinsics", "rotation", "translation"):
            bad["cameras"][2].pop(k, None)
        del sent[:]
        with pytest.raises(InvalidArgument):
            c.match_images(bad, *_paths(demo))
        assert sent == ["Match"]


def test_poses_as_quaternions_and_rounded_matrices(client, demo):
    cal = demo / "calibration.json"
    s = client.create_session(cal, name="poses")
    r = client.add_capture(s.id, {"quaternion": [1, 0, 0, 0], "translation": [0, 0, 0]},
                           images=_paths(demo))
    assert r.warnings == []
    c, sn = np.cos(0.3), np.sin(0.3)
    rounded = np.round([[c, -sn, 0, 0.1], [sn, c, 0, 0.2], [0, 0, 1, 0], [0, 0, 0, 1]], 4)
    r = client.add_capture(s.id, rounded, images=_paths(demo))
    assert len(r.warnings) == 1 and r.warnings[0].startswith("rig_to_world.matrix"), r.warnings
    client.delete_session(s.id)


def test_bad_pose_is_invalid(client, demo):
    s = client.create_session(demo / "calibration.json")
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(InvalidArgument) as e:
        client.add_capture(s.id, bad, images=_paths(demo))
    assert e.value.field.startswith("rig_to_world.matrix"), e.value.message
    with pytest.raises(InvalidArgument) as e:
        client.add_capture(s.id, IDENTITY, images=_paths(demo),
                           rig_to_world_covariance=np.ones((6, 6)) * 1e-4)
    assert e.value.field == "rig_to_world_covariance", e.value.message
    client.delete_session(s.id)


def test_calibrate_blank_images(client):
    blank = np.full((240, 320), 128, dtype=np.uint8)
    with pytest.raises(InvalidArgument) as e:
        client.calibrate(blank, blank, blank)
    # The three images are searched in parallel; any of them may be the one reported.
    assert e.value.field is not None and re.match(r"images\.images\[[012]\]", e.value.field), \
        e.value.message


def test_version():
    assert trinocular.__version__


def test_tls_with_a_private_certificate_and_an_api_key(tmp_path, demo):
    """The docs' Python form: `Client(target, ca_cert=..., api_key=...)` against
    `serve --tls-cert --tls-key`; a client without TLS gets UNAVAILABLE."""
    trustme = pytest.importorskip("trustme", reason="trustme (pip) makes the test certificate")
    ca = trustme.CA()
    issued = ca.issue_cert("localhost", "127.0.0.1")
    cert, key, root = tmp_path / "cert.pem", tmp_path / "key.pem", tmp_path / "ca.pem"
    issued.cert_chain_pems[0].write_to_path(str(cert))
    issued.private_key_pem.write_to_path(str(key))
    ca.cert_pem.write_to_path(str(root))
    api_key = "python-tls-test-key-0123456789"
    with _serve("--tls-cert", str(cert), "--tls-key", str(key),
                env={"TRINOCULAR_API_KEYS": f"py:{api_key}"}) as (grpc_addr, _):
        port = grpc_addr.rsplit(":", 1)[1]
        with Client(f"localhost:{port}", timeout=60, ca_cert=root, api_key=api_key) as c:
            r = c.match_images(demo / "calibration.json", *_paths(demo))
            assert len(r.segments_3d) > 0
            s = c.create_session(demo / "calibration.json", name="over-tls")
            assert c.get_session(s.id).id == s.id
        with Client(f"localhost:{port}", timeout=5, api_key=api_key) as plain:
            with pytest.raises(TrinocularError):
                plain.match_images(demo / "calibration.json", *_paths(demo))
