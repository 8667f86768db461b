"""The inputs of the active coarse stage (:func:`fgcd_cli.relocation.coarse.stage.run_coarse`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgcd_cli.relocation.coarse.config import CoarseConfig
from fgcd_cli.relocation.coarse.scene_uncertainty import SceneUncertaintyMap
from fgcd_cli.relocation.config import ReferenceData
from fgcd_cli.relocation.protocols import CameraModel
from fgcd_cli.relocation.session import VseSession
from fgcd_core.sim3 import Sim3

__all__ = ["CoarseInputs"]


@dataclass(frozen=True, kw_only=True)
class CoarseInputs:
    """The inputs of :func:`~fgcd_cli.relocation.coarse.stage.run_coarse`.

    Attributes
    ----------
    session : VseSession
        Running session (exploration done); every motion goes through its guard.
    reference : ReferenceData
        ``points`` (N, 3) metres and ``T_ref_camref`` (4, 4).
    ref_index : ReferenceIndex
        Search structure over the reference cloud.
    camera : CameraModel
        Undistorted intrinsics.
    scale : float
        Metres per map unit of this session.
    scale_rel_std : float
        One-sigma relative error of ``scale`` (the exploration's fit); the alignment's own scale is
        used by the check within three of them, or for an image estimate whenever the alignment
        measured it (:func:`~fgcd_cli.relocation.coarse.passive.check_scale`). 0: the session's
        scale is taken as exact (a metric session, or a caller that does not know its error).
    T_flange_cam : (4, 4) ndarray
        Hand-eye.
    init : Sim3
        First alignment ``T_ref_cur`` (the one that triggered the stage).
    reference_images, grab_current :
        For the image (PnP) localizer; without them only the 3D one runs.
    config : CoarseConfig
    evaluate : callable, optional
        Simulation only: truth for the log (evaluation code).
    say : callable(str)
        Progress lines for people.
    scene : callable() -> SceneUncertaintyMap or None, optional
        The reference observation's scene uncertainty map, asked for (and so computed) only when a
        look is chosen; None, or a None map: the looks keep their fixed order.
    """

    session: VseSession
    reference: ReferenceData
    ref_index: object
    camera: CameraModel
    scale: float
    T_flange_cam: np.ndarray
    init: Sim3
    scale_rel_std: float = 0.0
    reference_images: dict[str, np.ndarray] | None
    grab_current: Callable[[], np.ndarray] | None
    config: CoarseConfig = CoarseConfig()
    evaluate: Callable[[], dict] | None = None
    say: Callable[[str], None] = lambda _m: None
    scene: Callable[[], SceneUncertaintyMap | None] | None = None
