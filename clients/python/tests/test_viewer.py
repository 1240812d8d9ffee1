"""The Rerun helper (trinocular.viewer): a match and a session's map written to an .rrd file
by rerun-sdk, then read back through Rerun's own dataframe reader and compared with what the
service answered. Skipped, saying why, without rerun-sdk[catalog] (run_tests.sh installs it)."""

import os

import numpy as np
import pytest

rr = pytest.importorskip("rerun", reason="rerun-sdk is not installed (pip install 'trinocular[rerun]')")
pytest.importorskip("datafusion", reason="reading an .rrd back needs rerun-sdk[catalog] (datafusion)")

from test_client import IDENTITY, _paths, client, demo, server  # noqa: E402,F401  (fixtures)
from trinocular.viewer import colour, log_map, log_match  # noqa: E402

os.environ.setdefault("RERUN_ANALYTICS", "0")


def _write(path, log):
    rec = rr.RecordingStream("trinocular-test")
    rec.save(str(path))
    log(rec)
    rec.flush()
    rec.disconnect()


def _read(path, entity):
    """Every column of `entity` in the recording at `path`, as Python lists, by column name."""
    with rr.server.Server(port=None, datasets={"t": [str(path)]}) as server_:
        dataset = server_.client().get_dataset("t")
        table = dataset.filter_contents([entity]).reader(index=None).to_arrow_table()
    return {name: table.column(name).to_pylist() for name in table.column_names}


def test_a_match_is_written_to_rerun_and_reads_back_the_same(client, demo, tmp_path):
    cal = demo / "calibration.json"
    result = client.match_images(cal, *_paths(demo), options={"returnExtracted": True})
    assert len(result.segments_3d) > 0
    path = tmp_path / "match.rrd"
    _write(path, lambda rec: log_match(result, images=_paths(demo), calibration=cal, recording=rec))
    assert path.stat().st_size > 0

    columns = _read(path, "/match/world/segments_3d")
    strips = np.array(columns["/match/world/segments_3d:LineStrips3D:strips"][0], dtype=float)
    np.testing.assert_allclose(strips, result.segments_3d, rtol=1e-6, atol=1e-6)
    colours = columns["/match/world/segments_3d:LineStrips3D:colors"][0]
    r, g, b = colour(1)
    assert colours[1] == (r << 24) | (g << 16) | (b << 8) | 0xFF, "the overlay's colours"

    two_d = _read(path, "/match/images/cam1/segments")
    lines = two_d["/match/images/cam1/segments:LineStrips2D:strips"][0]
    assert len(lines) == len(result.extracted[0])
    image = _read(path, "/match/images/cam1")
    assert any(name.endswith("EncodedImage:blob") for name in image), list(image)
    cameras = _read(path, "/match/world/cameras")
    assert len(cameras["/match/world/cameras:Points3D:positions"][0]) == 3


def test_a_session_map_is_written_to_rerun_with_its_poses(client, demo, tmp_path):
    cal = demo / "calibration.json"
    s = client.create_session(cal, name="rerun")
    for _ in range(2):
        client.add_capture(s.id, IDENTITY, images=_paths(demo))
    m = client.get_map(s.id)
    path = tmp_path / "map.rrd"
    _write(path, lambda rec: log_map(m, calibration=cal, recording=rec))
    strips = _read(path, "/session/world/map")["/session/world/map:LineStrips3D:strips"][0]
    np.testing.assert_allclose(np.array(strips, dtype=float), m.segments, rtol=1e-6, atol=1e-6)
    poses = _read(path, "/session/world/poses")["/session/world/poses:Points3D:positions"][0]
    assert len(poses) == 2
    rig = _read(path, "/session/world/rig/1")
    translation = rig["/session/world/rig/1:Transform3D:translation"][0]
    np.testing.assert_allclose(np.reshape(translation, -1), m.poses[1][:3, 3], atol=1e-6)
    client.delete_session(s.id)
