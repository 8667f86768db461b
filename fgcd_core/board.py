"""Geometry of a ChArUco calibration board, shared by the simulator (renders it) and calibration (detects it).

A ChArUco board is a chessboard whose white squares hold ArUco markers. Board
frame (OpenCV's ChArUco convention): origin at the outer corner of the first
square, x along a row of squares, y down the columns, z into the board; metres.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import cv2
import numpy as np

__all__ = ["CharucoSpec", "DICTIONARIES"]

#: Supported ArUco dictionaries (name -> OpenCV constant).
DICTIONARIES: dict[str, int] = {
    name: getattr(cv2.aruco, name)
    for name in (
        "DICT_4X4_50",
        "DICT_4X4_100",
        "DICT_5X5_50",
        "DICT_5X5_100",
        "DICT_5X5_250",
        "DICT_6X6_50",
        "DICT_6X6_250",
        "DICT_APRILTAG_36h11",
    )
}

#: Markers of ``DICT_APRILTAG_36h11``, the one supported dictionary whose name does not end in its size.
_APRILTAG_36H11_SIZE = 587


@dataclass(frozen=True, kw_only=True)
class CharucoSpec:
    """Geometry of a ChArUco board.

    Attributes
    ----------
    squares_x, squares_y : int
        Chessboard squares along x (columns) and y (rows).
    square_m : float
        Side of one chessboard square, metres (measure the print!).
    marker_m : float
        Side of one ArUco marker, metres (< square_m).
    dictionary : str
        ArUco dictionary name, e.g. ``"DICT_5X5_100"`` (an OpenCV ``cv2.aruco`` constant).
    legacy_pattern : bool
        OpenCV < 4.6 board layout (only for boards printed by old tools).
    """

    squares_x: int = 10
    squares_y: int = 7
    square_m: float = 0.025
    marker_m: float = 0.018
    dictionary: str = "DICT_5X5_100"
    legacy_pattern: bool = False

    def problem(self) -> str | None:
        """Why this geometry is not a usable board (one line for a person), or None."""
        if self.squares_x < 3 or self.squares_y < 3:
            return "a ChArUco board needs at least 3 x 3 squares"
        if not (0 < self.marker_m < self.square_m):
            return (
                f"marker size {self.marker_m * 1000:.1f} mm must be positive and smaller than the square "
                f"{self.square_m * 1000:.1f} mm"
            )
        if self.dictionary not in DICTIONARIES:
            return f"unknown ArUco dictionary '{self.dictionary}'; choose from {', '.join(DICTIONARIES)}"
        n_markers = (self.squares_x * self.squares_y) // 2
        dict_size = int(self.dictionary.rsplit("_", 1)[-1]) if self.dictionary[-1].isdigit() else _APRILTAG_36H11_SIZE
        if n_markers > dict_size:
            return f"{n_markers} markers do not fit dictionary {self.dictionary}"
        return None

    def charuco_fields(self) -> dict:
        """The geometry alone, as keywords: ``SimBoard(**spec.charuco_fields(), margin_m=...)``."""
        return {f.name: getattr(self, f.name) for f in fields(CharucoSpec)}

    def cv_board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV board object."""
        board = cv2.aruco.CharucoBoard(
            (self.squares_x, self.squares_y),
            self.square_m,
            self.marker_m,
            cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)),
        )
        board.setLegacyPattern(self.legacy_pattern)
        return board

    @property
    def size_m(self) -> tuple[float, float]:
        """Board size (width, height) in metres, without margin."""
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    @property
    def n_corners(self) -> int:
        """Number of inner chessboard corners."""
        return (self.squares_x - 1) * (self.squares_y - 1)

    def corner_points(self) -> np.ndarray:
        """Board-frame coordinates of every chessboard corner, shape (n_corners, 3), metres."""
        return np.asarray(self.cv_board().getChessboardCorners(), dtype=float).reshape(-1, 3)

    def image(self, *, px_per_square: int = 100, margin_px: int = 0) -> np.ndarray:
        """Board image (uint8 grey, white margin of ``margin_px``), one square = ``px_per_square`` pixels."""
        w = self.squares_x * px_per_square + 2 * margin_px
        h = self.squares_y * px_per_square + 2 * margin_px
        return self.cv_board().generateImage((w, h), marginSize=margin_px, borderBits=1)
