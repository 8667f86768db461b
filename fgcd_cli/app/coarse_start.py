"""Whether a revisit starts with the active coarse stage (paper 001), and running it when it does."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgcd_cli.app.rig import RigHandles
from fgcd_cli.app.session import grab_gray, reference_images
from fgcd_cli.relocation.coarse.config import CoarseConfig, CoarseResult
from fgcd_cli.relocation.coarse.passive import image_estimate
from fgcd_cli.relocation.coarse.stage import run_coarse
from fgcd_cli.relocation.coarse.stage_inputs import CoarseInputs
from fgcd_cli.relocation.config import ReferenceData

__all__ = ["CoarseStart", "maybe_coarse"]


@dataclass(frozen=True, kw_only=True)
class CoarseStart:
    """The revisit's state when the coarse stage is considered.

    Attributes
    ----------
    rig : RigHandles
    session : VseSession
        The started session (its map scaled by ``scale``).
    reference : ReferenceData
    ref_index : ReferenceIndex
        The reference cloud's search structure.
    station : Station
        Whose reference images the image localizer reads.
    scale : float
        The session's map scale, metres per map unit.
    scale_rel_std : float
        Its one-sigma relative error (the exploration's fit); 0 takes the scale as exact.
    evaluate : callable() -> dict, or None
        The simulator's truth at the current pose (evaluation only).
    measured_images : dict of name -> (H, W) ndarray, or None
        The reference images the image localizer compares with (default: all the station's).
    grab_measured : callable() -> (H, W) ndarray, or None
        The current image it compares (default: a grey still under the day's light); with
        ``measured_images``, the image stage's own measurement (``app/relocate.py``), e.g. the lamp's
        own image.
    """

    rig: RigHandles
    session: object
    reference: ReferenceData
    ref_index: object
    station: object
    scale: float
    scale_rel_std: float = 0.0
    evaluate: Callable[[], dict] | None = None
    measured_images: dict | None = None
    grab_measured: Callable[[], np.ndarray] | None = None

    def images(self) -> dict:
        """The reference images the image localizer compares with."""
        return self.measured_images if self.measured_images is not None else reference_images(self.station)

    def current(self) -> np.ndarray:
        """The current image it compares."""
        return self.grab_measured() if self.grab_measured is not None else grab_gray(self.rig)


def maybe_coarse(
    start: CoarseStart, init, config: CoarseConfig, *, first_trusted: bool = True
) -> tuple[CoarseResult | None, object]:
    """Run the active coarse stage when the first estimate is far from the reference pose.

    An untrustworthy first alignment (a degenerate fit can claim the camera is near when it is
    not: a stupa's frieze slides along itself) is checked against the image localizer too;
    the stage runs when either puts the camera far away.

    Returns the stage's result (None when it did not run) and the alignment the rACR loop
    starts from: the stage's verified one, or the first one when the stage could not verify
    any (the loop then pauses on the far estimate and its image fallback tries, as before).
    """
    from fgcd_cli.relocation.adjustment import camera_in_reference
    from fgcd_core.se3 import pose_distance

    rig, session, reference = start.rig, start.session, start.reference
    state = session.tracking_state()
    T_cur_cam = np.array(state.T_map_cam, dtype=float)
    T_cur_cam[:3, 3] *= start.scale
    off_mm, off_deg = pose_distance(camera_in_reference(init, T_cur_cam), reference.T_ref_camref)
    source = "first estimate"
    near = off_mm <= config.trigger_m * 1e3 and off_deg <= config.trigger_deg
    if not near or not first_trusted:
        # A second opinion: a far 3D estimate may be a confidently wrong fit, a near one from an
        # untrustworthy fit may be a slide. When the image localizer puts the camera near, the loop
        # and its image fallback take it from there (docs/relocation.md, "Far starts").
        rig.progress(0, 0, "locating the camera in the reference images")
        with session.standing_still(stills=2):  # the platform waits for it, not for the simulator's rendering
            T_img, _info = image_estimate(
                reference_images=start.images(),
                current_image=start.current(),
                camera=rig.intrinsics,
                reference=reference,
            )
        if T_img is not None:
            img_mm, img_deg = pose_distance(T_img, reference.T_ref_camref)
            img_near = img_mm <= config.trigger_m * 1e3 and img_deg <= config.trigger_deg
            if near and not img_near:
                off_mm, off_deg, near = img_mm, img_deg, False
                source = "image estimate (the 3D one is untrustworthy)"
            elif not near and img_near:
                rig.say(
                    f"first estimate {off_mm:.0f} mm / {off_deg:.1f} deg from the reference, but the image "
                    f"localizer says {img_mm:.0f} mm / {img_deg:.1f} deg: no coarse stage"
                )
                near = True
    if near:
        return None, init
    rig.say(f"{source} {off_mm:.0f} mm / {off_deg:.1f} deg from the reference: active coarse stage")
    rig.progress(0, 0, "active coarse stage")
    result = run_coarse(
        CoarseInputs(
            session=session,
            reference=reference,
            ref_index=start.ref_index,
            camera=rig.intrinsics,
            scale=start.scale,
            scale_rel_std=start.scale_rel_std,
            T_flange_cam=rig.T_flange_cam,
            init=init,
            reference_images=start.images(),
            grab_current=start.current,
            config=config,
            evaluate=start.evaluate,
            say=rig.say,
            scene=lambda: _scene_map(start, config),
        )
    )
    if not result.handed_over:
        rig.say(f"{result.reason}; the rACR loop starts from the first estimate")
        return result, init
    return result, result.init


def _scene_map(start: CoarseStart, config: CoarseConfig):
    """The reference's scene uncertainty map (computed on the first look that needs it, then cached)."""
    from fgcd_cli.app.scene_uncertainty import station_scene_uncertainty

    start.rig.progress(0, 0, "scene uncertainty of the reference")
    return station_scene_uncertainty(start.station, start.rig.intrinsics, coarse=config, say=start.rig.say)
