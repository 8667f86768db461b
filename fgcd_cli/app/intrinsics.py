"""Use case: the camera intrinsics from views of a ChArUco board, and the printable board itself.

One flow for ``fgcd calibrate board`` / ``fgcd calibrate intrinsics`` and the
simulated campaigns of the demo and the benches
(:func:`fgcd_cli.app.calibrate.calibrate_sim_intrinsics`): the board from its
sidecar or its options, the views (photographs in a folder, or rendered by the
simulated rig's camera: :func:`sim_board_views`), the ChArUco calibration, and the
result stored in the campaign's rig.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fgcd_cli.errors import UserInputError

__all__ = [
    "BoardOptions",
    "IntrinsicsPlan",
    "IntrinsicsRequest",
    "board_spec",
    "load_board_images",
    "plan_intrinsics",
    "run_intrinsics",
    "sim_board_views",
    "store_intrinsics",
    "write_board",
]

ProgressCallback = Callable[[int, int, str], None]
#: The image files a folder of board photographs may hold.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


@dataclass(frozen=True, kw_only=True)
class BoardOptions:
    """A ChArUco board as given (``--board``, ``--squares-x`` ...).

    Attributes
    ----------
    board_file : Path or None
        Board sidecar JSON written by ``fgcd calibrate board`` (its geometry wins over the counts).
    squares_x, squares_y : int
        Squares along the board's width and height.
    square_mm : float or None
        Side of one square (the measured print; scales a sidecar's board). Default 25 mm.
    marker_mm : float or None
        Side of one marker (default 72 % of the square).
    dictionary : str
        ArUco dictionary.
    """

    board_file: Path | None = None
    squares_x: int = 10
    squares_y: int = 7
    square_mm: float | None = None
    marker_mm: float | None = None
    dictionary: str = "DICT_5X5_100"


def board_spec(options: BoardOptions):
    """The :class:`fgcd_cli.calibration.board.BoardSpec` of ``options``: the sidecar's (scaled to a measured
    ``square_mm``), else the counts and sizes given."""
    from fgcd_cli.calibration.board import BoardSpec, load_board_sidecar

    o = options
    if o.board_file is not None:
        board = load_board_sidecar(o.board_file)
        if o.square_mm is not None:  # the measured print overrides the nominal size
            ratio = o.square_mm / (board.square_m * 1000)
            board = BoardSpec(
                **{**board.__dict__, "square_m": board.square_m * ratio, "marker_m": board.marker_m * ratio}
            )
        return board
    square = 25.0 if o.square_mm is None else o.square_mm
    marker = o.marker_mm if o.marker_mm is not None else square * 0.72
    return BoardSpec(
        squares_x=o.squares_x,
        squares_y=o.squares_y,
        square_m=square / 1000,
        marker_m=marker / 1000,
        dictionary=o.dictionary,
    )


def write_board(options: BoardOptions, output: Path, *, dpi: int) -> tuple[Any, dict]:
    """Write a printable board (``.png`` or true-size ``.pdf``) and its sidecar ``<output>.json``.

    Returns
    -------
    tuple of (BoardSpec, dict)
        The board and the sidecar's content (page size, instructions).
    """
    from fgcd_cli.calibration.board import write_printable_board

    board = board_spec(BoardOptions(**{**options.__dict__, "board_file": None}))
    return board, write_printable_board(board, output, dpi=dpi)


def load_board_images(directory: Path) -> tuple[list[np.ndarray], list[str]]:
    """The grayscale images of a folder of board photographs and their file names (UserInputError)."""
    import cv2

    if not directory.is_dir():
        raise UserInputError(f"{directory} is not a directory of images")
    files = sorted(p for p in directory.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise UserInputError(f"no images (.png, .jpg, .tif, .bmp) in {directory}")
    images, names = [], []
    for p in files:
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise UserInputError(f"cannot read image {p}")
        images.append(img)
        names.append(p.name)
    return images, names


def sim_board_views(scenario, board, views: int, *, on_progress: ProgressCallback | None = None) -> list[np.ndarray]:
    """``views`` board views from the camera of the simulated rig of ``scenario`` (the one the hand-eye of that
    seed moves, not a stand-alone camera with other true intrinsics), each a tick of ``on_progress``."""
    from fgcd_cli.app.rig import open_sim_rig
    from fgcd_drivers.sim.board import SimBoard

    rig = open_sim_rig(scenario, T_flange_cam=None, intrinsics=None)
    try:
        source = rig.sim.board_camera(
            SimBoard(
                squares_x=board.squares_x,
                squares_y=board.squares_y,
                square_m=board.square_m,
                marker_m=board.marker_m,
                dictionary=board.dictionary,
            ),
            seed=scenario.seed,
        )
        images = []
        for k in range(views):
            if on_progress is not None:
                on_progress(k, views, "rendering board views")
            images.append(source.grab().image)
    finally:
        rig.close()
    return images


@dataclass(frozen=True, kw_only=True)
class IntrinsicsRequest:
    """What ``fgcd calibrate intrinsics`` should calibrate.

    Attributes
    ----------
    images : Path or None
        Folder of board photographs (exactly one of ``images`` and ``sim``).
    sim : bool
        Views of a board rendered by the simulated rig's camera.
    sim_views : int
        Number of simulated views (at least 1).
    seed : int or None
        Simulated rig whose camera is calibrated (None: the campaign's ``[rig.sim]`` seed, else 0).
    board : BoardOptions
        The board (with ``sim`` its sidecar is not read).
    distortion : str
        none, k1k2, k1k2p1p2 or k1k2p1p2k3.
    campaign : Path or None
        Store the result in this campaign's rig.
    """

    images: Path | None = None
    sim: bool = False
    sim_views: int = 20
    seed: int | None = None
    board: BoardOptions = BoardOptions()
    distortion: str = "k1k2p1p2"
    campaign: Path | None = None


@dataclass(frozen=True, kw_only=True)
class IntrinsicsPlan:
    """An intrinsics calibration checked before anything is rendered or read (:func:`plan_intrinsics`)."""

    request: IntrinsicsRequest
    campaign: Any
    seed: int


def plan_intrinsics(request: IntrinsicsRequest) -> IntrinsicsPlan:
    """Check the request (UserInputError, exit 2) and open its campaign (CampaignError, exit 3)."""
    from fgcd_cli.app.rig_options import calibration_campaign
    from fgcd_cli.campaign.records import campaign_world

    r = request
    if (r.images is None) == (not r.sim):
        raise UserInputError("give exactly one of --images DIR or --sim")
    campaign = calibration_campaign(r.campaign)
    # the hand-eye's rule: the option, else the campaign's [rig.sim] seed, else 0
    seed = r.seed if r.seed is not None else (campaign_world(campaign)["seed"] if campaign is not None else 0)
    if r.sim and r.sim_views < 1:
        raise UserInputError("--sim-views must be at least 1")
    return IntrinsicsPlan(request=r, campaign=campaign, seed=seed)


def run_intrinsics(plan: IntrinsicsPlan, *, on_progress: ProgressCallback | None = None):
    """Read or render the views of the plan and calibrate; the :class:`IntrinsicsResult` (nothing stored)."""
    from fgcd_cli.app.scenario import SimScenario
    from fgcd_cli.calibration.intrinsics import calibrate_intrinsics

    r = plan.request
    tick = on_progress or (lambda *_: None)
    if r.sim:
        board = board_spec(BoardOptions(**{**r.board.__dict__, "board_file": None}))
        images = sim_board_views(SimScenario(seed=plan.seed), board, r.sim_views, on_progress=tick)
        names = [f"sim_{i:03d}" for i in range(r.sim_views)]
    else:
        board = board_spec(r.board)
        images, names = load_board_images(r.images)
    tick(0, 0, "calibrating the intrinsics (ChArUco)")
    return calibrate_intrinsics(images, board, names=names, distortion_model=r.distortion)


def store_intrinsics(plan: IntrinsicsPlan, result) -> dict:
    """``fgcd calibrate intrinsics``'s record: the result, and where it was stored (``stored``) with a campaign."""
    from fgcd_cli.calibration.rig_files import save_intrinsics

    data = result.to_dict()
    if plan.campaign is not None:
        data["stored"] = save_intrinsics(plan.campaign, result)
    return data
