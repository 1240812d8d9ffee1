"""Test helper: renders what three cameras with lens distortion see of a planar checkerboard held in
front of them in several poses: the pictures OpenCV's calibrateCamera (Zhang's method) and
stereoCalibrate take. Area-sampled (3 × 3 rays a pixel), blurred 0.7 px, 2 grey levels of
noise, 8 bits: a decent camera in office light."""
import numpy as np
import cv2

COLS, ROWS, SQUARE = 9, 6, 0.025         # inner corners, square side (m)
SIZE = (640, 480)
TRUE = [
    (np.array([[600.0, 0, 321.0], [0, 600.0, 239.0], [0, 0, 1]]),
     np.array([-0.12, 0.05, 0.0005, -0.0003, 0.0]), np.zeros(3), np.zeros(3)),
    (np.array([[610.0, 0, 318.0], [0, 610.0, 242.0], [0, 0, 1]]),
     np.array([-0.10, 0.03, -0.0004, 0.0002, 0.0]), np.array([0.01, -0.04, 0.005]),
     np.array([-0.20, 0.0, 0.01])),
    (np.array([[595.0, 0, 324.0], [0, 595.0, 236.0], [0, 0, 1]]),
     np.array([-0.11, 0.04, 0.0, 0.0004, 0.0]), np.array([-0.03, 0.02, 0.0]),
     np.array([-0.10, 0.15, 0.02])),
]


def board_poses(rng, n, seen_by=(0, 1, 2)):
    """Board → camera 1 poses as a user takes them: the board's centre drawn over the whole of
    the first camera of `seen_by`'s picture, 0.45–0.9 m from it, tilted up to ±30°, kept when
    every corner is at least 15 px inside the pictures of all the cameras `seen_by` (so that,
    for one camera, corners reach the picture's edges, where distortion is largest)."""
    poses = []
    obj = object_points()
    centre = obj.mean(axis=0)
    K, _, r, tt = TRUE[seen_by[0]]
    Rk = cv2.Rodrigues(r)[0]
    while len(poses) < n:
        rvec = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3)])
        R = cv2.Rodrigues(rvec)[0]
        depth = rng.uniform(0.45, 0.9)
        u, v = rng.uniform(0, SIZE[0]), rng.uniform(0, SIZE[1])
        at_k = depth * np.array([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], 1.0])
        t = Rk.T @ (at_k - tt) - R @ centre
        inside = True
        for Kc, Dc, rc, tc in (TRUE[c] for c in seen_by):
            uv, _ = cv2.projectPoints(obj @ R.T + t, rc, tc, Kc, Dc)
            uv = uv.reshape(-1, 2)
            inside &= bool(((uv >= 15) & (uv <= np.array(SIZE) - 15)).all())
        if inside:
            poses.append((R, t))
    return poses


def object_points():
    g = np.mgrid[0:COLS, 0:ROWS].T.reshape(-1, 2) * SQUARE
    return np.column_stack([g, np.zeros(len(g))])


_RAYS = {}


def rays(camera, ss):
    """Camera k's ray (z = 1) through each of ss×ss points of every pixel, undistorted once."""
    key = (id(camera), ss)
    if key not in _RAYS:
        K, D = camera[0], camera[1]
        w, h = SIZE
        out = []
        for i in range(ss):
            for j in range(ss):
                u, v = np.meshgrid(np.arange(w) + (i + 0.5) / ss - 0.5, np.arange(h) + (j + 0.5) / ss - 0.5)
                pix = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
                crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
                n = cv2.undistortPoints(pix, K, D, None, None, criteria=crit).reshape(-1, 2)
                out.append(np.column_stack([n, np.ones(len(n))]))
        _RAYS[key] = out
    return _RAYS[key]


def render(camera, R_board, t_board, rng, ss=3):
    """The board as camera k sees it: each of ss×ss sub-pixel rays undistorted, intersected
    with the board plane, the square's colour looked up; averaged (area), blurred, noisy."""
    K, D, r, tt = camera
    Rk = cv2.Rodrigues(r)[0]
    # board → camera k
    R = Rk @ R_board
    t = Rk @ t_board + tt
    w, h = SIZE
    acc = np.zeros((h, w))
    normal = R[:, 2]  # the board's plane z = 0, through t
    for ray in rays(camera, ss):
        s = (normal @ t) / (ray @ normal)
        b = (ray * s[:, None] - t) @ R  # where each ray meets the board, board frame
        ix = np.floor(b[:, 0] / SQUARE + 1).astype(int)  # square columns 0..COLS on the board
        iy = np.floor(b[:, 1] / SQUARE + 1).astype(int)
        on_board = (ix >= 0) & (ix <= COLS) & (iy >= 0) & (iy <= ROWS) & (s > 0)
        # a white margin one square wide around the squares, then a grey wall
        margin = (ix >= -1) & (ix <= COLS + 1) & (iy >= -1) & (iy <= ROWS + 1) & (s > 0)
        dark = on_board & ((ix + iy) % 2 == 1)
        acc += np.where(dark, 30.0, np.where(margin, 220.0, 120.0)).reshape(h, w)
    img = cv2.GaussianBlur(acc / (ss * ss), (0, 0), 0.7)
    img += rng.normal(0, 2.0, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)
