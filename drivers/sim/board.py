"""A ChArUco calibration board in the simulated world.

Two uses:

- :func:`board_mesh_part` / :func:`add_board_to_scene`: the board as a textured
  plane of a :class:`fgcd_drivers.sim.scene.Scene`, so the simulated rig camera sees
  it through the scene renderer (hand-eye with a target);
- :func:`render_board_view`: an exact ray-cast image of the board alone for a
  camera with given intrinsics and distortion (intrinsic calibration views and
  tests). Every pixel's ray is undistorted with OpenCV and intersected with the
  board plane, supersampled to avoid aliasing.

Board frame (OpenCV's ChArUco convention): origin at the outer corner of the
first square, x along a row of squares, y down the columns, z into the board;
metres. The board's geometry is :class:`fgcd_core.board.CharucoSpec`, the one
calibration detects; the simulator adds only the printed margin.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_core.board import CharucoSpec
from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.sim.meshes import MeshPart, quad
from fgcd_drivers.sim.scene import Scene

__all__ = [
    "SimBoard",
    "BoardViewOptions",
    "board_texture",
    "board_mesh_part",
    "add_board_to_scene",
    "render_board_view",
    "random_board_poses",
    "BOARD_LABEL",
    "SimBoardCamera",
]

#: Label of the board in the renderer's label buffer.
BOARD_LABEL = 50


@dataclass(frozen=True, kw_only=True)
class SimBoard(CharucoSpec):
    """A printed ChArUco board: its geometry (:class:`~fgcd_core.board.CharucoSpec`) and white margin.

    Attributes
    ----------
    margin_m : float
        White margin around the squares, metres.
    """

    margin_m: float = 0.01


@dataclass(frozen=True, kw_only=True)
class BoardViewOptions:
    """Sensor and sampling of :func:`render_board_view`.

    Attributes
    ----------
    noise_sigma : float
        Gaussian sensor noise, in [0, 1] intensity units.
    blur_sigma_px : float
        Optical blur (Gaussian), pixels; 0 for none.
    background : float
        Intensity around the board, in [0, 1].
    supersample : int
        Rays per pixel along each axis (anti-aliasing).
    """

    noise_sigma: float = 1.5 / 255.0
    blur_sigma_px: float = 0.6
    background: float = 0.45
    supersample: int = 3


def board_texture(board: SimBoard, *, px_per_square: int = 64) -> tuple[np.ndarray, float, float]:
    """Board albedo with its white margin.

    Returns
    -------
    texture : (H, W) float32 ndarray
        Albedo in [0, 1] (black 0.04, white 0.9, like matte print).
    m_per_px : float
        Size of one texture pixel on the board, metres.
    margin_m : float
        The margin actually drawn (a whole number of texture pixels), metres.
    """
    m_per_px = board.square_m / px_per_square
    margin_px = int(round(board.margin_m / m_per_px))
    img = board.image(px_per_square=px_per_square, margin_px=margin_px)
    tex = 0.04 + (0.9 - 0.04) * (img.astype(np.float32) / 255.0)
    return tex, m_per_px, margin_px * m_per_px


def board_mesh_part(board: SimBoard, T_world_board: np.ndarray, *, px_per_square: int = 64) -> MeshPart:
    """The board (with margin) as a textured quad placed at ``T_world_board``.

    The texture's first row lies along the board's -y edge; texture coordinates
    run 0..1 across the quad (u along board x, v along board y).
    """
    tex, _, margin_m = board_texture(board, px_per_square=px_per_square)
    T = np.asarray(T_world_board, dtype=float)
    w, h = board.size_m
    w += 2 * margin_m
    h += 2 * margin_m
    origin = T[:3, :3] @ np.array([-margin_m, -margin_m, 0.0]) + T[:3, 3]
    vertices, triangles, tri_uv = quad(origin=origin, axis_u=T[:3, 0], axis_v=T[:3, 1], size_u=w, size_v=h)
    return MeshPart(
        name="charuco_board",
        label=BOARD_LABEL,
        vertices=vertices,
        triangles=triangles,
        tri_uv=tri_uv,
        texture=np.repeat(tex[:, :, None], 3, axis=2),
        texel_size_m=board.square_m / px_per_square,
        smooth=False,
    )


def add_board_to_scene(scene: Scene, board: SimBoard, T_world_board: np.ndarray) -> Scene:
    """Append the board to ``scene.parts`` (in place) and return the scene."""
    scene.parts.append(board_mesh_part(board, T_world_board))
    return scene


def render_board_view(
    board: SimBoard,
    T_cam_board: np.ndarray,
    camera: CameraIntrinsics,
    *,
    options: BoardViewOptions | None = None,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Grayscale uint8 image of the board seen by a pinhole camera with distortion.

    Every supersampled pixel's ray is undistorted and intersected with the
    board plane; the board texture is sampled there, box-filtered down to the
    pixel grid, then blurred, noised and quantised (:func:`_sensor`).

    Parameters
    ----------
    board : SimBoard
        Board geometry.
    T_cam_board : (4, 4) ndarray
        Board pose in the camera frame (OpenCV camera axes), metres.
    camera : CameraIntrinsics
        True intrinsics and OpenCV distortion ``(k1, k2, p1, p2, k3)``.
    options : BoardViewOptions, optional
        Sensor noise, blur, background and supersampling (defaults: :class:`BoardViewOptions`).
    rng : numpy Generator, optional
        Noise source (default: seeded with 0).

    Returns
    -------
    (height, width) uint8 ndarray
    """
    options = options or BoardViewOptions()
    rng = np.random.default_rng(0) if rng is None else rng
    ss = int(options.supersample)
    xy = _undistorted_grid(camera, ss)
    sampled = _sample_board(board, T_cam_board, xy, (camera.height * ss, camera.width * ss), options.background)
    img = cv2.resize(sampled, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    return _sensor(img, options, rng)


def _undistorted_grid(camera: CameraIntrinsics, ss: int) -> np.ndarray:
    """Normalised coordinates ``(x, y)``, shape (H*ss*W*ss, 2), of a supersampled pixel grid's rays.

    Sample ``i`` of pixel ``u`` sits at ``u + (i + 0.5) / ss - 0.5`` (pixel centres at integers).
    """
    us = (np.arange(camera.width * ss) + 0.5) / ss - 0.5
    vs = (np.arange(camera.height * ss) + 0.5) / ss - 0.5
    uu, vv = np.meshgrid(us, vs)
    pix = np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2)
    K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
    dist = np.asarray(camera.dist, dtype=float)
    if np.any(dist != 0):
        return cv2.undistortPointsIter(
            pix, K, dist, None, None, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-9)
        ).reshape(-1, 2)
    return np.column_stack([(pix[:, 0, 0] - camera.cx) / camera.fx, (pix[:, 0, 1] - camera.cy) / camera.fy])


def _sample_board(
    board: SimBoard, T_cam_board: np.ndarray, xy: np.ndarray, shape: tuple[int, int], background: float
) -> np.ndarray:
    """Board albedo seen along normalised rays ``xy`` (N, 2), as a float32 image of ``shape``.

    On the plane z_board = 0 a normalised ray ``(x, y, 1)`` is proportional to
    ``[r1 r2 t] (bx, by, 1)``; inverting that homography gives the board point.
    Rays that meet the plane behind the camera, and rays off the board, see
    ``background``.
    """
    tex, m_per_px, margin_m = board_texture(board)
    T = np.asarray(T_cam_board, dtype=float)
    H = np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]])
    rays = np.column_stack([xy, np.ones(len(xy))])
    b = rays @ np.linalg.inv(H).T
    with np.errstate(divide="ignore", invalid="ignore"):
        bx = b[:, 0] / b[:, 2]
        by = b[:, 1] / b[:, 2]
    # Depth along the ray must be positive (1 / b_z > 0 when H is built from a visible plane).
    front = b[:, 2] > 0
    map_x = ((bx + margin_m) / m_per_px - 0.5).astype(np.float32)
    map_y = ((by + margin_m) / m_per_px - 0.5).astype(np.float32)
    map_x[~front] = -1e6
    map_y[~front] = -1e6
    return cv2.remap(
        tex,
        map_x.reshape(shape),
        map_y.reshape(shape),
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=float(background),
    )


def _sensor(img: np.ndarray, options: BoardViewOptions, rng: np.random.Generator) -> np.ndarray:
    """Optical blur, additive Gaussian noise, and rounding to uint8 of a [0, 1] float image."""
    if options.blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), options.blur_sigma_px)
    img = img + rng.normal(0.0, options.noise_sigma, img.shape).astype(np.float32)
    return np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)


def random_board_poses(
    board: SimBoard,
    n: int,
    camera: CameraIntrinsics,
    *,
    distance_m: tuple[float, float] = (0.3, 0.6),
    max_tilt_deg: float = 40.0,
    rng: np.random.Generator | None = None,
) -> list[np.ndarray]:
    """Board poses ``T_cam_board`` covering the image (centre, edges, corners) with varied tilts.

    Each pose puts the board centre on the ray of a pixel drawn on a 3 x 3 grid
    of image regions in turn, at a random distance, tilted up to ``max_tilt_deg``
    about a random in-plane axis and rolled up to 30 degrees; poses whose board
    would show fewer than two of its four corners in the image are redrawn.
    The camera is taken without distortion here.
    """
    fx, fy, cx, cy, width, height = camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height
    rng = np.random.default_rng(0) if rng is None else rng
    w_m, h_m = board.size_m
    centre_local = np.array([w_m / 2, h_m / 2, 0.0])
    corners_local = np.array([[0, 0, 0], [w_m, 0, 0], [0, h_m, 0], [w_m, h_m, 0.0]])
    poses: list[np.ndarray] = []
    attempts = 0
    while len(poses) < n:
        attempts += 1
        if attempts > 200 * max(n, 1):
            raise RuntimeError("could not place the board in view; the camera field is too narrow")
        cell = len(poses) % 9
        gx, gy = cell % 3, cell // 3
        u = (gx + rng.uniform(0.2, 0.8)) / 3 * width
        v = (gy + rng.uniform(0.2, 0.8)) / 3 * height
        z = rng.uniform(*distance_m)
        centre = np.array([(u - cx) / fx * z, (v - cy) / fy * z, z])
        axis = np.array([np.cos(a := rng.uniform(0, 2 * np.pi)), np.sin(a), 0.0])
        tilt = np.radians(rng.uniform(10.0, max_tilt_deg)) if len(poses) % 4 else np.radians(rng.uniform(0, 15))
        R = cv2.Rodrigues(axis * tilt)[0] @ cv2.Rodrigues(np.array([0, 0, np.radians(rng.uniform(-30, 30))]))[0]
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = centre - R @ centre_local
        pc = corners_local @ R.T + T[:3, 3]
        if np.any(pc[:, 2] < 0.05):
            continue
        pu = fx * pc[:, 0] / pc[:, 2] + cx
        pv = fy * pc[:, 1] / pc[:, 2] + cy
        inside = (pu >= 0) & (pu < width) & (pv >= 0) & (pv < height)
        if inside.sum() < 2:
            continue
        poses.append(T)
    return poses


class SimBoardCamera:
    """A simulated camera looking at a hand-held board: each ``grab()`` shows a new pose.

    The true intrinsics differ from the nominal ones like a real camera's
    (``fgcd_drivers.sim.camera.perturbed_intrinsics``, seeded); only evaluation code
    reads :attr:`intrinsics_true` and :attr:`poses_true`.

    Parameters
    ----------
    board : SimBoard
    seed : int
        Seeds the true intrinsics, the board poses and the sensor noise.
    intrinsics_error : str or float
        ``"none"``, ``"default"``, ``"large"`` or a factor (see ``perturbed_intrinsics``).
    supersample : int
        Anti-aliasing rays per pixel and axis.
    """

    def __init__(
        self, board: SimBoard, *, seed: int = 0, intrinsics_error="default", supersample: int = 2, intrinsics_true=None
    ):
        from fgcd_drivers.cameras import Frame
        from fgcd_drivers.sim.camera import DEFAULT_INTRINSICS, perturbed_intrinsics

        self._frame_type = Frame
        self.board = board
        self.intrinsics_nominal = DEFAULT_INTRINSICS
        # ``intrinsics_true`` given: the same physical camera as a simulated rig (SimRig.board_camera)
        self.intrinsics_true = (
            intrinsics_true
            if intrinsics_true is not None
            else perturbed_intrinsics(DEFAULT_INTRINSICS, intrinsics_error, np.random.default_rng([seed, 0xB0A]))
        )
        self._rng = np.random.default_rng([seed, 0xB0B])
        self._supersample = supersample
        self.poses_true: list[np.ndarray] = []
        self._t = 0.0

    def grab(self):
        """Next view: the board at a new pose (cycling over image regions and tilts)."""
        # Draw one pose at a time, cycling the image cells like random_board_poses does for a list.
        k = len(self.poses_true)
        pose_rng = np.random.default_rng([int(self._rng.integers(1 << 31)), k])
        T = random_board_poses(self.board, k + 1, self.intrinsics_true, rng=pose_rng)[k]
        self.poses_true.append(T)
        image = render_board_view(
            self.board, T, self.intrinsics_true, options=BoardViewOptions(supersample=self._supersample), rng=self._rng
        )
        self._t += 0.5
        return self._frame_type(image, self._t)

    def close(self) -> None:
        """Nothing to release."""
