"""Results of the hand-eye calibrations: :class:`HandEyeResult` (with its residuals) and :class:`ScaleResult`."""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime

import numpy as np

__all__ = ["HandEyeResult", "ScaleResult", "utc_now"]


def utc_now() -> str:
    """Current UTC time as ISO 8601 text (seconds)."""
    return datetime.now(UTC).replace(microsecond=0).isoformat()


@dataclass(frozen=True, kw_only=True)
class HandEyeResult:
    """A hand-eye calibration, with what a person needs to judge it.

    Attributes
    ----------
    T_flange_cam : (4, 4) ndarray
        Hand-eye transform ``X`` (camera pose in the flange frame), metres.
    scale : float or None
        Map scale ``s`` in metres per VSE unit (target-free mode), None with a target.
    method : str
        Solver name (``"racr-linear"``, ``"TSAI"``...).
    n_samples, n_pairs : int
        Platform stops used and motion pairs formed from them.
    pairs : list of (int, int)
        The motion pairs, in the order of the residuals.
    residuals_mm, residuals_deg : (P,) ndarray
        Per-pair disagreement between ``M_B X`` and ``X M_A``: millimetres, degrees.
    sample_residuals_mm, sample_residuals_deg : (N,) ndarray
        Per-sample mean residual of the pairs involving that sample (find the bad stop).
    axis_spread_deg : float
        Spread of the rotation axes of the motions (0 = parallel, 90 = orthogonal).
    max_rotation_deg : float
        Largest flange rotation between two samples.
    created_utc : str
        When the result was computed.
    notes : list of str
        Warnings for the user (weak geometry, large residuals).
    refinement : dict
        Target-free mode: what the image refinement did (points, reprojection RMS,
        one-sigma uncertainty of ``X``, the linear solution it started from); empty
        when it did not run.
    """

    T_flange_cam: np.ndarray
    scale: float | None
    method: str
    n_samples: int
    n_pairs: int
    pairs: list[tuple[int, int]]
    residuals_mm: np.ndarray
    residuals_deg: np.ndarray
    sample_residuals_mm: np.ndarray
    sample_residuals_deg: np.ndarray
    axis_spread_deg: float
    max_rotation_deg: float
    created_utc: str = field(default_factory=utc_now)
    notes: list[str] = field(default_factory=list)
    refinement: dict = field(default_factory=dict)

    @property
    def rms_mm(self) -> float:
        """Root mean square of the per-pair translation residuals, mm."""
        return float(np.sqrt(np.mean(np.square(self.residuals_mm)))) if len(self.residuals_mm) else 0.0

    @property
    def rms_deg(self) -> float:
        """Root mean square of the per-pair rotation residuals, degrees."""
        return float(np.sqrt(np.mean(np.square(self.residuals_deg)))) if len(self.residuals_deg) else 0.0

    @property
    def worst_sample(self) -> int:
        """Index of the sample with the largest mean translation residual."""
        return int(np.argmax(self.sample_residuals_mm))

    def to_dict(self) -> dict:
        """JSON-friendly form (poses as nested lists, metres)."""
        return {
            "kind": "handeye",
            "T_flange_cam": np.asarray(self.T_flange_cam).tolist(),
            "scale": self.scale,
            "method": self.method,
            "n_samples": self.n_samples,
            "n_pairs": self.n_pairs,
            "pairs": [list(p) for p in self.pairs],
            "residuals_mm": np.asarray(self.residuals_mm).tolist(),
            "residuals_deg": np.asarray(self.residuals_deg).tolist(),
            "sample_residuals_mm": np.asarray(self.sample_residuals_mm).tolist(),
            "sample_residuals_deg": np.asarray(self.sample_residuals_deg).tolist(),
            "rms_mm": self.rms_mm,
            "rms_deg": self.rms_deg,
            "axis_spread_deg": self.axis_spread_deg,
            "max_rotation_deg": self.max_rotation_deg,
            "created_utc": self.created_utc,
            "notes": list(self.notes),
            "refinement": dict(self.refinement),
        }

    @classmethod
    def from_dict(cls, data: dict) -> HandEyeResult:
        """Inverse of :meth:`to_dict`."""
        return cls(
            T_flange_cam=np.array(data["T_flange_cam"], dtype=float),
            scale=None if data.get("scale") is None else float(data["scale"]),
            method=str(data["method"]),
            n_samples=int(data["n_samples"]),
            n_pairs=int(data["n_pairs"]),
            pairs=[(int(i), int(j)) for i, j in data.get("pairs", [])],
            residuals_mm=np.array(data.get("residuals_mm", []), dtype=float),
            residuals_deg=np.array(data.get("residuals_deg", []), dtype=float),
            sample_residuals_mm=np.array(data.get("sample_residuals_mm", []), dtype=float),
            sample_residuals_deg=np.array(data.get("sample_residuals_deg", []), dtype=float),
            axis_spread_deg=float(data.get("axis_spread_deg", float("nan"))),
            max_rotation_deg=float(data.get("max_rotation_deg", float("nan"))),
            created_utc=str(data.get("created_utc", "")),
            notes=list(data.get("notes", [])),
            refinement=dict(data.get("refinement", {})),
        )


@dataclass(frozen=True, kw_only=True)
class ScaleResult:
    """Map scale of one VSE session with the hand-eye known.

    Attributes
    ----------
    scale : float
        Metres per VSE unit.
    scale_std : float
        One-sigma uncertainty of ``scale`` from the least-squares residuals (inflated by
        ``sqrt(pairs / (samples - 1))``: pairs sharing a sample share its error).
    n_pairs : int
        Motion pairs used.
    residuals_mm : (P,) ndarray
        Per-pair translation disagreement after scaling, millimetres.
    rotation_residuals_deg : (P,) ndarray
        Per-pair rotation disagreement ``M_B X`` vs ``X M_A`` (checks the hand-eye), degrees.
    created_utc : str
        When it was computed.
    """

    scale: float
    scale_std: float
    n_pairs: int
    residuals_mm: np.ndarray
    rotation_residuals_deg: np.ndarray
    created_utc: str = field(default_factory=utc_now)

    @property
    def rms_mm(self) -> float:
        """Root mean square translation residual, mm."""
        return float(np.sqrt(np.mean(np.square(self.residuals_mm))))

    def to_dict(self) -> dict:
        """JSON-friendly form."""
        return {
            "kind": "scale",
            "scale": self.scale,
            "scale_std": self.scale_std,
            "n_pairs": self.n_pairs,
            "residuals_mm": np.asarray(self.residuals_mm).tolist(),
            "rotation_residuals_deg": np.asarray(self.rotation_residuals_deg).tolist(),
            "rms_mm": self.rms_mm,
            "created_utc": self.created_utc,
        }

    @classmethod
    def from_dict(cls, data: dict) -> ScaleResult:
        """Inverse of :meth:`to_dict`."""
        return cls(
            scale=float(data["scale"]),
            scale_std=float(data["scale_std"]),
            n_pairs=int(data["n_pairs"]),
            residuals_mm=np.array(data["residuals_mm"], dtype=float),
            rotation_residuals_deg=np.array(data["rotation_residuals_deg"], dtype=float),
            created_utc=str(data.get("created_utc", "")),
        )
