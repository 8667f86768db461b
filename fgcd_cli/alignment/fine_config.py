"""Options of the fine-grained alignment (:func:`fgcd_cli.alignment.fine.fine_align`).

Kept apart from the solver so that the loop's configuration can hold them
without importing it.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["FineAlignConfig"]


@dataclass(frozen=True, kw_only=True)
class FineAlignConfig:
    """Options of :func:`fine_align`."""

    alpha: float = 0.2
    """Weight of the geometric term (the paper's alpha)."""
    refine_keyframes: bool = True
    """False skips Eq. (16) (the paper's rACR-P ablation)."""
    estimate_scale: bool = False
    """Refine the scale here too (the paper's Eq. 18). Off by default: the scale
    then stays the fast stage's (Eq. 14, from ``E_g``). ``E_p`` sees the scale,
    and the shift along the viewing direction that goes with it on a nearly flat
    object, only through the parallax between the current keyframes, i.e.
    through the monocular trajectory, whose scale disagrees with its own cloud
    (bas-relief ambiguity of small motions); on a stele Eq. 18 moves the camera
    along the optical axis and worsens the result (docs/alignment.md,
    "Fine-grained alignment")."""
    blur_sigmas: tuple[float, ...] = (3.0, 1.0)
    """Gaussian blur (pixels) of each level, coarse to fine."""
    keyframe_iterations: int = 5
    similarity_iterations: int = 5
    max_photometric_points: int = 2000
    max_geometric_points: int = 3000
    min_photometric_sigma: float = 0.004
    """Floor of the robust photometric residual scale (grey levels in [0, 1])."""
    occlusion_cell_px: int = 4
    occlusion_depth_tol: float = 0.01
    max_keyframes: int = 8
    """Only the last ``max_keyframes`` keyframes are used."""
    max_rotation_change_deg: float = 3.0
    """Health: larger changes from ``init`` are not trusted."""
    max_scale_change: float = 0.05
    max_translation_change_rel: float = 0.05
    """Fraction of the reference width."""
    seed: int = 0
