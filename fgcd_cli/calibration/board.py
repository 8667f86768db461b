"""ChArUco calibration board: geometry, printable image, detection.

A ChArUco board is a chessboard whose white squares hold ArUco markers: the
markers identify each chessboard corner, so partial and tilted views still give
corners with known board coordinates. Detection uses OpenCV's
``cv2.aruco.CharucoDetector``. The board frame has its origin at the outer
corner of the first square, x along the squares' rows, y along the columns,
z into the board (OpenCV's convention); lengths in metres.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fgcd_cli.campaign.atomic import atomic_write_bytes, atomic_write_json
from fgcd_cli.errors import UserInputError
from fgcd_core.board import DICTIONARIES, CharucoSpec
from fgcd_core.imaging import U8Rounding, to_gray_u8

__all__ = ["BoardSpec", "BoardDetection", "DICTIONARIES", "write_printable_board", "load_board_sidecar"]

MM_PER_INCH = 25.4


@dataclass(frozen=True, kw_only=True)
class BoardDetection:
    """ChArUco corners found in one image.

    Attributes
    ----------
    corners_px : (K, 2) float ndarray
        Sub-pixel chessboard corner positions.
    ids : (K,) int ndarray
        Corner ids (index into :meth:`BoardSpec.corner_points`).
    n_markers : int
        ArUco markers detected.
    """

    corners_px: np.ndarray
    ids: np.ndarray
    n_markers: int

    @property
    def n_corners(self) -> int:
        """Number of chessboard corners found."""
        return int(len(self.ids))


@dataclass(frozen=True, kw_only=True)
class BoardSpec(CharucoSpec):
    """Geometry of a ChArUco board (:class:`fgcd_core.board.CharucoSpec`), checked on construction,
    with its detection and persistence.

    Raises
    ------
    UserInputError
        The geometry is not a usable board (:meth:`CharucoSpec.problem`).
    """

    def __post_init__(self) -> None:
        problem = self.problem()
        if problem is not None:
            raise UserInputError(problem)

    # -- detection
    def detect(self, image: np.ndarray) -> BoardDetection:
        """Find ChArUco corners in an image (uint8 or float in [0, 1], gray or RGB; Rec. 601 luma)."""
        gray = to_gray_u8(image, rounding=U8Rounding.HALF_UP_F64)
        detector = cv2.aruco.CharucoDetector(self.cv_board())
        corners, ids, marker_corners, marker_ids = detector.detectBoard(gray)
        n_markers = 0 if marker_ids is None else len(marker_ids)
        if ids is None or corners is None or len(ids) == 0:
            return BoardDetection(corners_px=np.zeros((0, 2)), ids=np.zeros(0, dtype=int), n_markers=n_markers)
        return BoardDetection(
            corners_px=np.asarray(corners, dtype=float).reshape(-1, 2),
            ids=np.asarray(ids, dtype=int).ravel(),
            n_markers=n_markers,
        )

    def estimate_pose(self, detection: BoardDetection, K: np.ndarray, dist) -> np.ndarray | None:
        """Board pose in the camera ``T_cam_board`` (4x4, metres) by ``solvePnP``; None if too few corners."""
        if detection.n_corners < 6:
            return None
        obj = self.corner_points()[detection.ids]
        ok, rvec, tvec = cv2.solvePnP(obj, detection.corners_px, np.asarray(K, float), np.asarray(dist, float))
        if not ok:
            return None
        rvec, tvec = cv2.solvePnPRefineLM(
            obj, detection.corners_px, np.asarray(K, float), np.asarray(dist, float), rvec, tvec
        )
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(rvec)[0]
        T[:3, 3] = tvec.ravel()
        return T

    # -- persistence
    def to_dict(self) -> dict:
        """JSON-friendly geometry (lengths in metres and millimetres for people)."""
        return {
            "type": "charuco",
            "squares_x": self.squares_x,
            "squares_y": self.squares_y,
            "square_m": self.square_m,
            "marker_m": self.marker_m,
            "square_mm": self.square_m * 1000,
            "marker_mm": self.marker_m * 1000,
            "dictionary": self.dictionary,
            "legacy_pattern": self.legacy_pattern,
        }

    @classmethod
    def from_dict(cls, data: dict) -> BoardSpec:
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(
                squares_x=int(data["squares_x"]),
                squares_y=int(data["squares_y"]),
                square_m=float(data["square_m"]),
                marker_m=float(data["marker_m"]),
                dictionary=str(data.get("dictionary", "DICT_5X5_100")),
                legacy_pattern=bool(data.get("legacy_pattern", False)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise UserInputError(f"board description is incomplete or malformed: {exc}") from exc


def write_printable_board(board: BoardSpec, path: Path, *, dpi: int = 300, margin_mm: float = 10.0) -> dict:
    """Write a printable board (PNG or PDF at true size) and its JSON sidecar ``<path>.json``.

    Parameters
    ----------
    board : BoardSpec
        Geometry to print.
    path : Path
        Output file; ``.png`` (with DPI metadata) or ``.pdf`` (page = board + margins).
    dpi : int
        Resolution of the raster (PNG pixels, PDF embedded image).
    margin_mm : float
        White margin around the board.

    Returns
    -------
    dict
        The sidecar content: geometry, page size, dpi, print instructions.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".pdf"):
        raise UserInputError(f"board output must end in .png or .pdf, not '{path.suffix}'")
    if dpi < 72 or dpi > 1200:
        raise UserInputError("dpi must be between 72 and 1200")
    px_per_mm = dpi / MM_PER_INCH
    px_per_square = int(round(board.square_m * 1000 * px_per_mm))
    margin_px = int(round(margin_mm * px_per_mm))
    image = board.image(px_per_square=px_per_square, margin_px=margin_px)
    page_mm = (image.shape[1] / px_per_mm, image.shape[0] / px_per_mm)
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".png":
        ok, buf = cv2.imencode(".png", image)
        if not ok:
            raise UserInputError(f"could not encode the board image for {path}")
        atomic_write_bytes(path, _png_with_dpi(buf.tobytes(), dpi))
    else:
        atomic_write_bytes(path, _pdf_bytes(image, page_mm))
    printed_square_mm = px_per_square / px_per_mm
    sidecar = {
        "board": board.to_dict(),
        "file": path.name,
        "dpi": dpi,
        "margin_mm": margin_mm,
        "page_mm": [round(page_mm[0], 3), round(page_mm[1], 3)],
        "printed_square_mm": printed_square_mm,
        "instructions": (
            "Print at 100 % (no 'fit to page'), glue flat on a rigid plate, then measure one square with "
            "calipers; if it is not exactly square_mm, pass the measured value with --square-mm."
        ),
    }
    atomic_write_json(Path(str(path) + ".json"), sidecar)
    return sidecar


def load_board_sidecar(path: Path) -> BoardSpec:
    """Board geometry from a sidecar written by :func:`write_printable_board` (or a bare board dict)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise UserInputError(f"board file not found: {path}") from exc
    except json.JSONDecodeError as exc:
        raise UserInputError(f"board file {path} is not valid JSON: {exc.msg}") from exc
    return BoardSpec.from_dict(data.get("board", data))


def _png_with_dpi(png: bytes, dpi: int) -> bytes:
    """Insert a pHYs chunk (pixels per metre) so printers keep the true size.

    OpenCV's encoder writes no resolution; the chunk is 21 bytes after IHDR
    (PNG spec §11.3.5.3), simpler than adding an imaging library for it.
    """
    import struct
    import zlib

    ppm = int(round(dpi / 0.0254))
    body = b"pHYs" + struct.pack(">IIB", ppm, ppm, 1)
    chunk = struct.pack(">I", 9) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    ihdr_end = 8 + 4 + 4 + 13 + 4
    return png[:ihdr_end] + chunk + png[ihdr_end:]


def _pdf_bytes(image: np.ndarray, page_mm: tuple[float, float]) -> bytes:
    """One-page PDF of exactly ``page_mm`` holding the image edge to edge (matplotlib's PDF backend)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(page_mm[0] / MM_PER_INCH, page_mm[1] / MM_PER_INCH))
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.imshow(image, cmap="gray", vmin=0, vmax=255, interpolation="nearest", aspect="auto")
    ax.set_axis_off()
    out = io.BytesIO()
    fig.savefig(out, format="pdf")
    return out.getvalue()
