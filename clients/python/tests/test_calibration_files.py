"""Calibration files of other tools through the service: a file that OpenCV itself writes
(cv2.FileStorage, YAML and XML) imports with the same projections as OpenCV's own
cv2.projectPoints to 1e-9 px, and what the service exports OpenCV reads back. Skipped, saying
why, without opencv-python-headless (run_tests.sh installs it)."""

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is not installed")

from test_client import client, server  # noqa: E402,F401  (fixtures)
from trinocular import InvalidArgument  # noqa: E402

# Camera 1's frame from the rig's (x right, y forward, z up → x right, y down, z forward).
A = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])

CAMERAS = [
    (np.array([[600.0, 0.2, 320.5], [0, 598.0, 241.2], [0, 0, 1]]),
     np.array([-0.21, 0.07, 0.001, -0.0005, -0.01]), np.zeros(3), np.zeros(3)),
    (np.array([[605.0, 0, 318.0], [0, 603.5, 236.9], [0, 0, 1]]),
     np.array([-0.19, 0.05, -0.0007, 0.0003, 0.0]), np.array([0.01, -0.03, 0.004]),
     np.array([-0.30, 0.002, 0.01])),
    (np.array([[598.0, 0, 322.4], [0, 597.1, 244.0], [0, 0, 1]]),
     np.array([-0.2, 0.06, 0.0, 0.0002, 0.004]), np.array([-0.02, -0.015, 0.0]),
     np.array([-0.15, -0.25, 0.02])),
]


def _write(path):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for k, (K, D, rvec, tvec) in enumerate(CAMERAS, start=1):
        fs.write(f"cameraMatrix{k}", K)
        fs.write(f"distCoeffs{k}", D.reshape(1, 5))
        if k > 1:
            fs.write(f"R1{k}", cv2.Rodrigues(rvec)[0])
            fs.write(f"T1{k}", tvec.reshape(3, 1))
    fs.write("imageSize", np.array([640, 480]))
    fs.release()


def _ours(camera, points_rig):
    """Projections by an imported camera (K, R, t and distortion of the Calibration JSON)."""
    K = np.array(camera["intrinsics"]).reshape(3, 3)
    R = np.array(camera["rotation"]).reshape(3, 3)
    t = np.array(camera["translation"])
    d = camera.get("distortion", {})
    k1, k2, p1, p2, k3 = (d.get(n, 0.0) for n in ("k1", "k2", "p1", "p2", "k3"))
    c = points_rig @ R.T + t
    x, y = c[:, 0] / c[:, 2], c[:, 1] / c[:, 2]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)


@pytest.mark.parametrize("suffix,format", [(".yaml", "opencv-yaml"), (".xml", "opencv-xml")])
def test_a_file_opencv_writes_imports_with_opencvs_projections(client, tmp_path, suffix, format):
    path = tmp_path / f"stereo{suffix}"
    _write(path)
    calibration = client.import_calibration(format, [path])
    cameras = calibration["cameras"]
    assert [(c["width"], c["height"]) for c in cameras] == [(640, 480)] * 3
    rng = np.random.default_rng(1)
    points_cam1 = np.column_stack([rng.uniform(-1, 1, 50), rng.uniform(-0.7, 0.7, 50),
                                   rng.uniform(2, 6, 50)])
    points_rig = points_cam1 @ A  # x_rig = Aᵀ x_cam1
    worst = 0.0
    for camera, (K, D, rvec, tvec) in zip(cameras, CAMERAS):
        theirs, _ = cv2.projectPoints(points_cam1, rvec, tvec, K, D)
        worst = max(worst, np.abs(_ours(camera, points_rig) - theirs.reshape(-1, 2)).max())
    assert worst < 1e-9, f"{worst} px from cv2.projectPoints"

    # What the service exports, OpenCV reads: the same matrices (the skew OpenCV ignores is
    # not kept).
    exported = client.export_calibration(format, calibration)
    assert len(exported) == 1
    back = tmp_path / f"back{suffix}"
    back.write_text(exported[0])
    fs = cv2.FileStorage(str(back), cv2.FILE_STORAGE_READ)
    for k, (K, D, rvec, tvec) in enumerate(CAMERAS, start=1):
        unskewed = K.copy()
        unskewed[0, 1] = 0.0
        np.testing.assert_allclose(fs.getNode(f"cameraMatrix{k}").mat(), unskewed, atol=1e-9)
        np.testing.assert_allclose(fs.getNode(f"distCoeffs{k}").mat().ravel(), D, atol=1e-12)
        if k > 1:
            np.testing.assert_allclose(fs.getNode(f"R1{k}").mat(), cv2.Rodrigues(rvec)[0], atol=1e-12)
            np.testing.assert_allclose(fs.getNode(f"T1{k}").mat().ravel(), tvec, atol=1e-12)
    fs.release()
    # export → import is the identity.
    again = client.import_calibration(format, [exported[0]])
    for a, b in zip(again["cameras"], cameras):
        for key in ("intrinsics", "rotation", "translation"):
            np.testing.assert_allclose(a[key], b[key], atol=1e-12)


def test_a_fisheye_chain_is_refused_naming_the_model(client):
    chain = ("cam0:\n  camera_model: pinhole\n  distortion_model: equidistant\n"
             "  intrinsics: [400, 400, 320, 240]\n  distortion_coeffs: [0.1, 0, 0, 0]\n"
             "  resolution: [640, 480]\n")
    with pytest.raises(InvalidArgument) as e:
        client.import_calibration("kalibr", [chain])
    assert e.value.field == "cam0.distortion_model"
    assert "equidistant" in str(e.value)


# What a usable calibration must reach against the true cameras on scene points, pixels: the
# usual acceptance of a calibration's reprojection error. (Trinocular's own `calibrate` is held
# to 0.2 px in tests/integration/calibration.rs; OpenCV's calibration of these renders lands at
# 0.05–0.31 px over eight draws of the board poses, its own error, which the import does not
# change: the imported cameras are also compared with OpenCV's projections to 1e-9 px.)
CALIBRATION_RMS_PX = 0.5


def test_calibrate_with_opencv_then_import(client, tmp_path):
    """The documented path for a rig calibrated with a planar checkerboard (docs/
    CALIBRATION_FILES.md): sixteen views of the board per camera and sixteen all three see,
    OpenCV's calibrateCamera (Zhang's method) per camera, stereoCalibrate from camera 1 to
    cameras 2 and 3, the result written with cv2.FileStorage under the names stereoCalibrate's
    samples use and imported by the service: the imported cameras project as OpenCV's, and put
    scene points where the true cameras do."""
    import checkerboard as cb

    rng = np.random.default_rng(3)
    board = cb.object_points().astype(np.float32)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4)

    def views(n, seen_by):
        """The board's corners in `n` poses as each camera of `seen_by` finds them; a pose
        where one does not find the board is dropped, as a user drops that picture."""
        found = [[] for _ in seen_by]
        while len(found[0]) < n:
            (R, t), = cb.board_poses(rng, 1, seen_by)
            pictures = [cb.render(cb.TRUE[k], R, t, rng) for k in seen_by]
            detected = [cv2.findChessboardCorners(p, (cb.COLS, cb.ROWS)) for p in pictures]
            if all(ok for ok, _ in detected):
                for f, p, (_, c) in zip(found, pictures, detected):
                    f.append(cv2.cornerSubPix(p, c, (5, 5), (-1, -1), criteria))
        return found

    # Each camera's own sixteen views, the board over its whole picture (intrinsics), then sixteen
    # views all three cameras see (extrinsics).
    own = [views(16, (k,))[0] for k in range(3)]
    shared = views(16, (0, 1, 2))
    fs = cv2.FileStorage(str(tmp_path / "stereo.yaml"), cv2.FILE_STORAGE_WRITE)
    Ks, Ds, extrinsics = [], [], [(np.eye(3), np.zeros((3, 1)))]
    for k in range(3):
        rms, K, D, _, _ = cv2.calibrateCamera([board] * 16, own[k], cb.SIZE, None, None)
        assert rms < 0.5, f"camera {k + 1}: OpenCV's own RMS {rms} px"
        Ks.append(K)
        Ds.append(D)
        fs.write(f"cameraMatrix{k + 1}", K)
        fs.write(f"distCoeffs{k + 1}", D)
    for k in (1, 2):
        out = cv2.stereoCalibrate([board] * 16, shared[0], shared[k], Ks[0], Ds[0], Ks[k], Ds[k],
                                  cb.SIZE, flags=cv2.CALIB_FIX_INTRINSIC)
        print(f"stereo 1-{k + 1}: RMS {out[0]:.3f} px")
        extrinsics.append((out[5], out[6]))
        fs.write(f"R1{k + 1}", out[5])
        fs.write(f"T1{k + 1}", out[6])
    fs.write("imageSize", np.array(cb.SIZE))
    fs.release()

    calibration = client.import_calibration("opencv-yaml", [tmp_path / "stereo.yaml"])
    points_cam1 = np.column_stack([rng.uniform(-0.6, 0.6, 400), rng.uniform(-0.45, 0.45, 400),
                                   rng.uniform(0.7, 3.0, 400)])
    points_cam1[:, :2] *= points_cam1[:, 2:] / 1.5  # spread with depth, to fill the view
    truths = []
    for K, D, rvec, tvec in cb.TRUE:
        truth, _ = cv2.projectPoints(points_cam1, rvec, tvec, K, D)
        truth = truth.reshape(-1, 2)
        truths.append((truth, ((truth >= 0) & (truth < np.array(cb.SIZE))).all(axis=1)))
    # The imported rig frame is camera 1's frame as OpenCV estimated it: a principal point a
    # pixel off turns it by a tenth of a degree, which moves no 3D segment relative to the rig.
    # That rotation is fitted once, on camera 1's projections (Gauss-Newton on a rotation
    # vector, camera 1 at the origin as in both frames); cameras 2 and 3 then test the rig's
    # geometry itself.
    truth1, seen1 = truths[0]

    def camera1_residual(rvec):
        ours, _ = cv2.projectPoints(points_cam1[seen1], rvec, np.zeros(3), Ks[0], Ds[0])
        return (ours.reshape(-1, 2) - truth1[seen1]).ravel()

    rvec = np.zeros(3)
    for _ in range(10):
        r0 = camera1_residual(rvec)
        J = np.column_stack([(camera1_residual(rvec + 1e-7 * e) - r0) / 1e-7 for e in np.eye(3)])
        rvec = rvec - np.linalg.lstsq(J, r0, rcond=None)[0]
    aligned = points_cam1 @ cv2.Rodrigues(rvec)[0].T
    points_rig = aligned @ A
    for k, (camera, (truth, seen)) in enumerate(zip(calibration["cameras"], truths)):
        assert seen.sum() > 200
        # Imported as OpenCV calibrated it.
        R, T = extrinsics[k]
        theirs, _ = cv2.projectPoints(points_cam1, cv2.Rodrigues(R)[0], T, Ks[k], Ds[k])
        gap = np.abs(_ours(camera, points_cam1 @ A) - theirs.reshape(-1, 2)).max()
        assert gap < 1e-9, f"camera {k + 1}: {gap} px from OpenCV's own projections"
        # Against the true camera, up to the frame's rotation.
        d = _ours(camera, points_rig[seen]) - truth[seen]
        rms = float(np.sqrt((d ** 2).sum(axis=1).mean()))
        print(f"camera {k + 1}: {rms:.3f} px RMS over {seen.sum()} scene points")
        assert rms <= CALIBRATION_RMS_PX, f"camera {k + 1}: {rms:.3f} px RMS against the true camera"
