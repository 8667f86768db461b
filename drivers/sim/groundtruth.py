"""Ground truth of a simulated rig: the ONLY interface evaluation code reads it through.

Algorithms (fgcd_cli/vse, calibration, alignment, relocation, changes) never
touch this; metrics, benchmarks and tests do.
"""

from __future__ import annotations

import numpy as np

from fgcd_core.camera import CameraIntrinsics

__all__ = ["GroundTruth"]


class GroundTruth:
    """True poses, hand-eye, intrinsics, depths, change masks and ids and AFD of a simulated rig."""

    def __init__(
        self, *, world, platform, T_world_base: np.ndarray, T_flange_cam: np.ndarray, intrinsics_true: CameraIntrinsics
    ):
        self._world = world
        self._platform = platform
        self._T_world_base = np.asarray(T_world_base, float).copy()
        self._T_flange_cam = np.asarray(T_flange_cam, float).copy()
        self._intr = intrinsics_true

    def _set_T_world_base(self, T: np.ndarray) -> None:
        """Move the platform base (the rig was set up again); simulator internal."""
        self._T_world_base = np.asarray(T, float).copy()

    # -- poses
    def T_world_base_true(self) -> np.ndarray:
        return self._T_world_base.copy()

    def T_flange_cam_true(self) -> np.ndarray:
        return self._T_flange_cam.copy()

    def T_base_flange_true(self) -> np.ndarray:
        return self._platform.true_flange_pose()

    def T_world_cam_true(self) -> np.ndarray:
        """True camera pose now: ``T_world_base @ T_base_flange_true @ T_flange_cam``."""
        return self._T_world_base @ self._platform.true_flange_pose() @ self._T_flange_cam

    def T_world_cam_for_flange(self, T_base_flange: np.ndarray) -> np.ndarray:
        """Camera pose the rig would have with the flange exactly at ``T_base_flange``."""
        return self._T_world_base @ np.asarray(T_base_flange, float) @ self._T_flange_cam

    def intrinsics_true(self) -> CameraIntrinsics:
        return self._intr

    def platform_rotation_scale_true(self) -> float:
        """Ratio of the simulated platform's executed to commanded rotations (its kinematic error)."""
        return float(getattr(self._platform, "_rot_scale", 1.0))

    # -- images
    def depth(self, T_world_cam: np.ndarray | None = None, intrinsics: CameraIntrinsics | None = None) -> np.ndarray:
        """(H, W) float32 z-depth in metres (0 where nothing), current changes included."""
        T = self.T_world_cam_true() if T_world_cam is None else T_world_cam
        res = self._world.renderer.render(
            T, intrinsics or self._intr, None, changes=self._world.changes, want=("depth",)
        )
        return res.depth

    def change_mask(
        self, T_world_cam: np.ndarray | None = None, intrinsics: CameraIntrinsics | None = None, changes=None
    ) -> np.ndarray:
        """(H, W) bool mask of the changes (default: those applied to the world) seen from a camera."""
        T = self.T_world_cam_true() if T_world_cam is None else T_world_cam
        ch = self._world.changes if changes is None else changes
        res = self._world.renderer.render(T, intrinsics or self._intr, None, changes=ch, want=("labels",))
        return res.change_mask

    def change_ids(
        self, T_world_cam: np.ndarray | None = None, intrinsics: CameraIntrinsics | None = None, changes=None
    ) -> np.ndarray:
        """(H, W) int32: 0 where no change, else 1 + the change's index in ``changes`` (default: :meth:`changes`).

        Same pixels as :meth:`change_mask`; where footprints overlap, the strongest wins.
        """
        T = self.T_world_cam_true() if T_world_cam is None else T_world_cam
        ch = self._world.changes if changes is None else changes
        res = self._world.renderer.render(T, intrinsics or self._intr, None, changes=ch, want=("labels",))
        return res.change_ids

    def labels(self, T_world_cam: np.ndarray | None = None, intrinsics: CameraIntrinsics | None = None) -> np.ndarray:
        T = self.T_world_cam_true() if T_world_cam is None else T_world_cam
        return self._world.renderer.render(T, intrinsics or self._intr, None, want=("labels",)).labels

    def changes(self) -> list:
        return list(self._world.changes)

    def true_afd_px(
        self,
        T_world_cam_ref: np.ndarray,
        T_world_cam_cur: np.ndarray,
        intrinsics: CameraIntrinsics | None = None,
        *,
        step_px: int = 8,
    ) -> float:
        """True average feature displacement (pixels) between two views, without matching.

        Reference pixels on a regular grid (every ``step_px``) are back-projected
        with the rendered reference depth, projected into the current camera
        (same intrinsics, distortion ignored: a pinhole AFD), and the mean length
        of their displacement is returned; points leaving the current image or
        occluded there (depth disagreeing by > 1 %) are left out. NaN if none remain.
        """
        intr = intrinsics or self._intr
        pinhole = CameraIntrinsics(fx=intr.fx, fy=intr.fy, cx=intr.cx, cy=intr.cy, width=intr.width, height=intr.height)
        d_ref = self.depth(T_world_cam_ref, pinhole)
        d_cur = self.depth(T_world_cam_cur, pinhole)
        vs, us = np.mgrid[step_px // 2 : intr.height : step_px, step_px // 2 : intr.width : step_px]
        z = d_ref[vs, us]
        ok = z > 0
        u, v, z = us[ok].astype(float), vs[ok].astype(float), z[ok].astype(float)
        p_ref = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], 1)
        T_cur_ref = np.linalg.inv(T_world_cam_cur) @ T_world_cam_ref
        p = p_ref @ T_cur_ref[:3, :3].T + T_cur_ref[:3, 3]
        front = p[:, 2] > 1e-6
        uc = intr.fx * p[:, 0] / np.where(front, p[:, 2], 1) + intr.cx
        vc = intr.fy * p[:, 1] / np.where(front, p[:, 2], 1) + intr.cy
        inside = front & (uc >= 0) & (uc <= intr.width - 1) & (vc >= 0) & (vc <= intr.height - 1)
        ui = np.clip(np.round(uc).astype(int), 0, intr.width - 1)
        vi = np.clip(np.round(vc).astype(int), 0, intr.height - 1)
        visible = inside & (np.abs(d_cur[vi, ui] - p[:, 2]) < 0.01 * p[:, 2])
        if not visible.any():
            return float("nan")
        return float(np.mean(np.hypot(uc[visible] - u[visible], vc[visible] - v[visible])))
