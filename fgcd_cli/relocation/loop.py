"""The rACR relocation loop: VSE thread, alignment thread, adjustment thread (paper 000, Fig. 2).

* the VSE thread (``fgcd_cli.vse.thread.VseThread``) keeps the latest camera pose
  and cloud of the current session;
* the alignment thread (:class:`AlignmentWorker`) aligns the latest cloud to the
  reference, fast then fine, again and again, and publishes its latest
  similarity ``T_ref_cur``;
* the adjustment thread (the caller of :func:`run_relocation`) combines the
  latest pose and the latest similarity into a hand motion (Eq. 3, see
  :mod:`fgcd_cli.relocation.adjustment`), sends it through the motion guard, and
  stops when ``g <= eta``.

Hand-over between threads is "latest value" under a lock: nobody waits for
anybody except the adjustment thread, which needs one estimate newer than its
previous motion. ``mode="serial"`` runs the same steps one after the other
(the paper's Table 5 baseline). A failing VSE or alignment pauses motion
instead of guessing.
"""

from __future__ import annotations

import json
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from fgcd_cli.errors import AlgorithmError
from fgcd_cli.geometry.se3 import pose_distance
from fgcd_cli.geometry.sim3 import Sim3
from fgcd_cli.relocation.adjustment import Adjustment, compute_adjustment
from fgcd_cli.relocation.session import VseSession

__all__ = [
    "ReferenceData",
    "RelocationConfig",
    "AlignmentEstimate",
    "AlignmentWorker",
    "AdjustmentRecord",
    "RelocationResult",
    "Residual",
    "align_once",
    "estimates_agree",
    "reference_depth_m",
    "run_relocation",
    "tolerance_mm",
]


@dataclass(frozen=True, kw_only=True)
class ReferenceData:
    """What relocation needs of a reference observation (all in the ref frame, metres).

    Attributes
    ----------
    points : (N, 3) ndarray
        Reference metric cloud.
    intensities : (N,) ndarray
        Grey value of each point in [0, 1].
    T_ref_camref : (4, 4) ndarray
        The reference camera pose.
    """

    points: np.ndarray
    intensities: np.ndarray
    T_ref_camref: np.ndarray


@dataclass(frozen=True, kw_only=True)
class RelocationConfig:
    """Options of the loop.

    Attributes
    ----------
    mode : {"parallel", "serial"}
        Three threads with latest-value hand-over, or everything in turn.
    eta : float
        Stop when ``g = ||M_B - I||_F <= eta`` (paper: 1e-4).
    max_adjustments : int
        Give up after this many adjustments.
    max_step_m, max_step_rad : float
        Largest motion of one adjustment (also enforced by the guard).
    fine : bool
        Run the fine-grained stage after the fast one (``-F`` ablation when False).
    min_points : int
        Current cloud size needed before aligning.
    estimate_timeout_s : float
        Longest wait for a fresh alignment before pausing with an error.
    stop_afd_px : float
        Also stop when the remaining motion, as estimated, would move the
        reference image by less than this many pixels on average (the
        estimated AFD). ``g <= eta`` is the paper's rule; with monocular
        estimates whose noise is above ``eta`` this image-space rule is what
        ends a relocation, at the accuracy the paper scores (AFD in pixels).
    """

    mode: str = "parallel"
    eta: float = 1e-4
    max_adjustments: int = 12
    max_step_m: float = 0.05
    max_step_rad: float = math.radians(10.0)
    fine: bool = True
    min_points: int = 500
    estimate_timeout_s: float = 120.0
    stop_afd_px: float = 0.5
    divergence_factor: float = 1.5
    divergence_margin_mm: float = 10.0
    divergence_margin_deg: float = 1.0
    divergence_patience: int = 2
    """Pause with an error when the estimated offset exceeds ``factor x best + margin``
    this many adjustments in a row (the loop should shrink it every time)."""
    max_offset_m: float = 0.25
    max_offset_deg: float = 20.0
    """Pause (and let the image fallback try) when an estimate puts the camera farther than this
    from the reference pose: rACR starts a revisit within a few centimetres (the exploration moves
    4 cm), so such an estimate is a confidently wrong alignment, or a start that needs the active
    coarse stage first. Measured (bench relocate, outdoor-5, statue, serial): a first estimate at
    1.19 m, trusted, led the loop 50 mm the wrong way before the divergence stop fired."""
    image_refine: bool = True
    """After the 3D loop converges, refine from the reference images
    (:mod:`fgcd_cli.relocation.image_refine`) when the evidence is strong."""
    image_refine_steps: int = 4
    image_stop_afd_px: float = 0.5
    """The image stage stops when its correction moves the reference image by less than this.
    The same 0.5 px as ``stop_afd_px``: the image measurement itself is only good to about
    0.3 px across lightings (simulator: measured 0.38 px where the truth was 0.31 px, then moved
    4.5 mm for no gain), so a lower bar makes the stage chase its own noise for 5-10 s a step."""
    image_fallback: bool = True
    """When the 3D alignment stays untrustworthy (degenerate geometry such as a
    flat wall, too few inliers, divergence), try the image stage before pausing:
    it needs no alignment of the current cloud, only the reference images and
    cloud. It acts only on strong evidence; otherwise the loop pauses as before."""
    image_fallback_steps: int = 6
    untrusted_patience: int = 6
    untrusted_min_wait_s: float = 20.0
    """Pause early (instead of waiting ``estimate_timeout_s``) after this many
    consecutive untrustworthy estimates, once at least this long was waited."""
    degenerate_patience: int = 3
    """Pause at once after this many consecutive estimates flagged as degenerate
    geometry (plane, sphere, body of revolution): a property of the scene, which
    waiting does not cure, unlike too few inliers in a young map."""
    tolerance_mm: float | None = None
    """Largest remaining camera offset (mm) any stage may stop on. ``None``: the model of
    :func:`tolerance_mm` (the sideways camera shift that moves the object's image by
    ``stop_afd_px`` at the reference camera's distance; docs/relocation.md, "Stop rules")."""
    vse_sigma_rel: float = 0.01
    """1-sigma uncertainty of a 3D (cloud-alignment) estimate of the camera position, as a
    fraction of the camera distance: two monocular sessions place their cameras relative to
    their clouds to about 1 % of the depth (docs/relocation.md, "Final image stage")."""
    agreement_k: float = 2.0
    """Two estimates agree when their camera positions differ by at most ``k`` times the
    RMS radius of their combined uncertainty (:func:`estimates_agree`)."""
    agreement_wait_s: float = 30.0
    """Longest wait for a 3D estimate of the view after the last image motion, to check
    agreement; without one, the check is reported as not done."""


@dataclass(frozen=True, kw_only=True)
class AlignmentEstimate:
    """One published alignment."""

    T_ref_cur: Sim3
    stage: str  # "fast" | "fine"
    ok: bool
    reason: str
    vse_frame: int  # frames_processed of the VSE state it used
    seconds: float
    serial: int  # increasing publication number
    degenerate: bool = False  # the health check found the geometry degenerate (not noise: the scene)


def _scaled_pose(T_map_cam: np.ndarray, scale: float) -> np.ndarray:
    T = np.array(T_map_cam, dtype=float)
    T[:3, 3] *= scale
    return T


def _local_cloud(state, recent_keyframes: int, *, min_points: int = 3000) -> np.ndarray:
    """Cloud points of the most recent keyframes (the local map around the current camera).

    A monocular map drifts in scale over a session; the points measured from
    the latest keyframes are consistent with the latest camera pose, which is
    what the adjustment needs. Falls back to the whole cloud when the local
    part is too small.
    """
    pts = np.asarray(state.cloud.points, dtype=float)
    ids = np.asarray(getattr(state.cloud, "keyframe_ids", np.zeros(0)))
    if recent_keyframes <= 0 or len(ids) != len(pts) or not state.keyframes:
        return pts
    recent = {kf.id for kf in state.keyframes[-recent_keyframes:]}
    keep = np.isin(ids, list(recent))
    return pts[keep] if keep.sum() >= min_points else pts


def align_once(
    *,
    state,
    scale: float,
    reference: ReferenceData,
    ref_index,
    camera,
    init: Sim3,
    fine: bool,
    serial: int = 0,
    recent_keyframes: int = 6,
) -> list[AlignmentEstimate]:
    """Fast (then fine) alignment of one VSE state; returns the estimates it produced."""
    from fgcd_cli.alignment import fast_align, fine_align

    out: list[AlignmentEstimate] = []
    cur_points = _local_cloud(state, recent_keyframes) * scale
    t0 = time.monotonic()
    fast = fast_align(cur_points, ref_index, init=init)
    out.append(
        AlignmentEstimate(
            T_ref_cur=fast.T_ref_cur,
            stage="fast",
            ok=bool(fast.health.ok),
            reason=fast.health.reason,
            vse_frame=state.frames_processed,
            seconds=time.monotonic() - t0,
            serial=serial,
            degenerate=bool(fast.health.degenerate),
        )
    )
    if fine and fast.health.ok and len(state.keyframes) >= 2:
        t1 = time.monotonic()
        kfs = [(_scaled_pose(kf.T_map_cam, scale), kf.image) for kf in state.keyframes[-6:]]
        res = fine_align(
            ref_points=ref_index if ref_index is not None else reference.points,
            ref_intensities=reference.intensities,
            cur_keyframes=kfs,
            camera=camera,
            init=fast.T_ref_cur,
            cur_points=cur_points,
        )
        out.append(
            AlignmentEstimate(
                T_ref_cur=res.T_ref_cur,
                stage="fine",
                ok=bool(res.health.ok),
                reason=res.health.reason,
                vse_frame=state.frames_processed,
                seconds=time.monotonic() - t1,
                serial=serial + 1,
                degenerate=bool(res.health.degenerate),
            )
        )
    return out


class AlignmentWorker:
    """The alignment thread: aligns the latest VSE state again and again."""

    def __init__(self, *, vse, scale: float, reference: ReferenceData, ref_index, camera, init: Sim3, fine: bool, min_points: int):
        self._vse = vse
        self._scale = scale
        self._reference = reference
        self._ref_index = ref_index
        self._camera = camera
        self._init = init
        self._fine = fine
        self._min_points = min_points
        self._lock = threading.Lock()
        self._latest: AlignmentEstimate | None = None
        self._last_ok: AlignmentEstimate | None = None  # starting point of the next run
        self._serial = 0
        self._stop = threading.Event()
        self._error: str | None = None
        self._thread = threading.Thread(target=self._run, name="fgcd-alignment", daemon=True)

    def start(self) -> "AlignmentWorker":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=120)  # one alignment run at most; never leave it inside native code

    @property
    def error(self) -> str | None:
        return self._error

    def latest(self) -> AlignmentEstimate | None:
        with self._lock:
            return self._latest

    def latest_ok(self) -> AlignmentEstimate | None:
        """The newest trustworthy estimate, if the newest published one is trustworthy."""
        with self._lock:
            return self._latest if self._latest is not None and self._latest.ok else None

    def _run(self) -> None:
        last_frame = -1
        try:
            while not self._stop.is_set():
                state = self._vse.latest()
                if (
                    state.status != "tracking"
                    or len(state.cloud) < self._min_points
                    or state.frames_processed == last_frame
                ):
                    time.sleep(0.01)
                    continue
                last_frame = state.frames_processed
                init = self._last_ok.T_ref_cur if self._last_ok is not None else self._init
                for est in align_once(
                    state=state,
                    scale=self._scale,
                    reference=self._reference,
                    ref_index=self._ref_index,
                    camera=self._camera,
                    init=init,
                    fine=self._fine,
                    serial=self._serial + 1,
                ):
                    with self._lock:
                        self._serial = est.serial
                        # a failed estimate is published too (the loop pauses on it) but never
                        # replaces the starting point of the next run
                        self._latest = est
                    if est.ok:
                        self._last_ok = est
                    if self._stop.is_set():
                        break
        except Exception as exc:  # noqa: BLE001 - reported to the adjustment thread, which stops
            self._error = f"{type(exc).__name__}: {exc}"


@dataclass(frozen=True, kw_only=True)
class AdjustmentRecord:
    """One line of ``relocation.jsonl``."""

    iteration: int
    t_wall_s: float
    t_session_s: float
    stage: str
    g: float
    offset_mm: float
    offset_deg: float
    T_ref_cam: list
    M_flange_commanded: list
    clamped: bool
    vse_status: str
    vse_points: int
    alignment_ok: bool
    alignment_reason: str
    scale: float
    sigma: float
    afd_est_px: float
    truth: dict | None = None
    image: dict | None = None
    """Image stage only: matches, inliers, RMS, measured AFD, reference image."""
    estimate_serial: int | None = None
    estimate_vse_frame: int | None = None
    """3D stages: the alignment estimate used (its publication number and the VSE frame it saw);
    in parallel mode a motion may reuse an estimate of the view before the previous motion."""
    offset_sigma_mm: float | None = None
    """1-sigma uncertainty of ``offset_mm`` (RMS radius of the camera position's uncertainty):
    PnP residual covariance for the image stage, ``vse_sigma_rel`` x distance for 3D stages."""
    tolerance_mm: float | None = None
    """The stop tolerance on ``offset_mm`` the run used (:func:`tolerance_mm`)."""
    agreement: dict | None = None
    """Image stage: the 3D estimate of the same view it was compared with, and the verdict."""

    def to_json(self) -> str:
        return json.dumps(self.__dict__, ensure_ascii=False)


@dataclass
class RelocationResult:
    """Outcome of a relocation."""

    converged: bool
    reason: str
    adjustments: int
    records: list[AdjustmentRecord] = field(default_factory=list)
    final_T_ref_cam: np.ndarray | None = None
    wall_s: float = 0.0
    session_s: float = 0.0
    platform_s: float = 0.0
    synthetic_s: float = 0.0
    """Frame-synthesis time left out of ``session_s`` (simulator rendering; 0 on hardware)."""
    residual: "Residual | None" = None
    """The final remaining offset as the tool estimates it, with its uncertainty."""


@dataclass(frozen=True, kw_only=True)
class Residual:
    """The remaining camera offset at the end of a run, as the tool's own estimate says.

    Attributes
    ----------
    offset_mm : float
        Distance between the current and the reference camera centres, mm.
    sigma_mm : float
        Its 1-sigma uncertainty (RMS radius of the position's uncertainty), mm.
    tolerance_mm : float
        The stop tolerance the run used, mm.
    source : str
        "image" (PnP on the reference images) or "3d" (cloud alignment).
    agreement : str
        How the other estimator compared ("agree", "disagree", "not checked: ...").
    """

    offset_mm: float
    sigma_mm: float
    tolerance_mm: float
    source: str
    agreement: str = "not checked"

    def text(self) -> str:
        """One phrase for people: ``residual 0.99 ± 0.23 mm (image estimate; tolerance 1.36 mm)``."""
        return (f"residual {self.offset_mm:.2f} ± {self.sigma_mm:.2f} mm ({self.source} estimate; "
                f"tolerance {self.tolerance_mm:.2f} mm; 3D/image: {self.agreement})")

    def to_dict(self) -> dict:
        """Plain data for JSON output."""
        return dict(self.__dict__)


def reference_depth_m(ref_points: np.ndarray, T_ref_camref: np.ndarray) -> float:
    """Median depth of the reference cloud in front of the reference camera, metres.

    Parameters
    ----------
    ref_points : (N, 3) ndarray
        Reference cloud, metres, ``ref`` frame.
    T_ref_camref : (4, 4) ndarray
        Reference camera pose.

    Returns
    -------
    float
        NaN when no point is in front of the camera.
    """
    P = np.asarray(ref_points, dtype=float).reshape(-1, 3)
    T = np.asarray(T_ref_camref, dtype=float)
    z = (P - T[:3, 3]) @ T[:3, 2]
    z = z[z > 1e-6]
    return float(np.median(z)) if len(z) else math.nan


def tolerance_mm(ref_points: np.ndarray, T_ref_camref: np.ndarray, camera, *, stop_afd_px: float) -> float:
    """Stop tolerance on the remaining camera offset, mm (docs/relocation.md, "Stop rules").

    Model: a sideways camera shift ``d`` at distance ``Z`` moves the object's image by
    ``f d / Z`` pixels, so the image-space stop rule (``stop_afd_px``) corresponds to
    ``d = stop_afd_px * Z / f``: the pixel footprint on the object times the pixel
    tolerance. A shift that a small turn hides (a nearly flat object) escapes the AFD,
    not this rule.

    Parameters
    ----------
    ref_points : (N, 3) ndarray
        Reference cloud, metres.
    T_ref_camref : (4, 4) ndarray
        Reference camera pose.
    camera : PinholeCamera or None
        Intrinsics (``fx``, ``fy`` in pixels).
    stop_afd_px : float
        The image-space stop rule, pixels.

    Returns
    -------
    float
        Millimetres; ``inf`` without a camera or a cloud in front of it (no model: the
        paper's ``g <= eta`` rule stands alone).
    """
    if camera is None:
        return math.inf
    z = reference_depth_m(ref_points, T_ref_camref)
    f = 0.5 * (float(camera.fx) + float(camera.fy))
    if not math.isfinite(z) or f <= 0:
        return math.inf
    return 1000.0 * stop_afd_px * z / f


def estimates_agree(offset_a_mm: np.ndarray, sigma_a_mm: float, offset_b_mm: np.ndarray, sigma_b_mm: float, *,
                    k: float) -> tuple[bool, float, float]:
    """Whether two estimates of the camera position agree within their uncertainties.

    Parameters
    ----------
    offset_a_mm, offset_b_mm : (3,) ndarray
        Camera centre minus the reference camera centre, ``ref`` frame, mm.
    sigma_a_mm, sigma_b_mm : float
        Their RMS-radius uncertainties, mm; a non-finite one (an estimator that gave
        none) counts as 0, so the bound rests on the other.
    k : float
        Allowed multiple of the combined RMS radius ``sqrt(sa^2 + sb^2)``. For an
        isotropic error, ``|e| > 2 x RMS radius`` has probability ~0.7 % (chi-square, 3 dof).

    Returns
    -------
    agree : bool
    distance_mm : float
        ``|a - b|``.
    bound_mm : float
        ``k sqrt(sa^2 + sb^2)``.
    """
    d = float(np.linalg.norm(np.asarray(offset_a_mm, dtype=float) - np.asarray(offset_b_mm, dtype=float)))
    sa, sb = (float(x) if math.isfinite(float(x)) else 0.0 for x in (sigma_a_mm, sigma_b_mm))
    bound = k * math.hypot(sa, sb)
    return bool(d <= bound), d, bound


def _offset_vector_mm(T_ref_cam: np.ndarray, T_ref_camref: np.ndarray) -> np.ndarray:
    """Current minus reference camera centre, ``ref`` frame, mm, shape (3,)."""
    return 1000.0 * (np.asarray(T_ref_cam, dtype=float)[:3, 3] - np.asarray(T_ref_camref, dtype=float)[:3, 3])


#: Longest silence (s) while the loop waits for an alignment: a progress line at least this often.
HEARTBEAT_S = 5.0


@dataclass
class _LoopShared:
    """What the 3D loop leaves for the image stage: its latest estimate and the tolerances."""

    tol_mm: float
    sigma3d_mm: float
    last_T_ref_cur: Sim3 | None = None
    moved_at_frame: int = -1


def _say(session, text: str) -> None:
    """A progress line through the session's plain callback (the CLI renders it)."""
    if getattr(session, "on_event", None):
        session.on_event(text)


def _racr_loop(*, session, reference, ref_index, camera, scale, T_flange_cam, init, config, evaluate,
               on_record, worker, records, t_start, shared: _LoopShared) -> RelocationResult:
    """The 3D rACR loop: align, adjust, until converged; raises AlgorithmError when it pauses.

    It stops when the paper's rule (``g <= eta``) or the image-space rule (estimated AFD
    ``<= stop_afd_px``) holds *and* the estimated remaining offset is within the tolerance
    (:func:`tolerance_mm`): a stage never stops while its own estimate says more remains.
    """
    result = RelocationResult(False, "not started", 0)
    current_init = init
    last_serial = 0
    best_offset: tuple[float, float] | None = None  # smallest estimated remaining offset so far (mm, deg)
    growths = 0
    moved_at_frame = -1  # VSE frame count when the last motion ended

    def adjustment_for(est: AlignmentEstimate, state) -> Adjustment:
        return compute_adjustment(
            T_ref_cur=est.T_ref_cur,
            T_cur_cam=_scaled_pose(state.T_map_cam, scale),
            T_ref_camref=reference.T_ref_camref,
            T_flange_cam=T_flange_cam,
            max_step_m=config.max_step_m,
            max_step_rad=config.max_step_rad,
        )

    def afd_of(adj: Adjustment) -> float:
        return estimated_afd_px(reference.points, reference.T_ref_camref, adj.T_ref_cam, camera)

    def stops(adj: Adjustment, afd_est_px: float) -> bool:
        return (adj.g <= config.eta or afd_est_px <= config.stop_afd_px) and adj.offset_mm <= shared.tol_mm

    for iteration in range(1, config.max_adjustments + 1):
        state = session.tracking_state()
        if config.mode == "parallel":
            # Latest-value hand-over (paper Fig. 2): T_ref_cur maps the session's map frame, which
            # does not move with the camera, so the latest trustworthy estimate and the VSE's
            # current pose give the next motion without waiting for an alignment of the new view.
            # Only the decision to stop waits for an estimate computed after the last motion.
            latest = worker.latest_ok() if iteration > 1 else None
            if latest is not None and latest.serial >= last_serial:
                est = latest
            else:
                _say(session, f"adjustment {iteration}: waiting for an alignment of the current view")
                est = _wait_for_estimate(worker, last_serial, config, session)
            state = session.vse.latest() if session.vse.latest().status == "tracking" else state
        else:
            t0 = time.monotonic()
            _say(session, f"adjustment {iteration}: aligning the current cloud to the reference")
            if len(state.cloud) < config.min_points:
                raise AlgorithmError(f"the VSE cloud has only {len(state.cloud)} points: cannot align")
            ests = align_once(
                state=state,
                scale=scale,
                reference=reference,
                ref_index=ref_index,
                camera=camera,
                init=current_init,
                fine=config.fine,
                serial=last_serial + 1,
            )
            session.timing.wait_s += time.monotonic() - t0
            oks = [e for e in ests if e.ok]
            est = oks[-1] if oks else ests[-1]
            if not est.ok:
                raise AlgorithmError(f"alignment failed, motion paused: {est.reason}")
        adj = adjustment_for(est, state)
        afd_est = afd_of(adj)
        while config.mode == "parallel" and est.vse_frame < moved_at_frame and stops(adj, afd_est):
            # About to stop on an estimate of the view before the last motion: confirm it first.
            _say(session, f"adjustment {iteration}: confirming the stop on an alignment of the current view")
            est = _wait_for_estimate(worker, est.serial, config, session)
            state = session.vse.latest() if session.vse.latest().status == "tracking" else state
            adj = adjustment_for(est, state)
            afd_est = afd_of(adj)
        last_serial = est.serial
        current_init = est.T_ref_cur
        shared.last_T_ref_cur = est.T_ref_cur
        rec = AdjustmentRecord(
            iteration=iteration,
            t_wall_s=time.monotonic() - t_start,
            t_session_s=session.timing.total_s,
            stage=est.stage,
            g=adj.g,
            offset_mm=adj.offset_mm,
            offset_deg=adj.offset_deg,
            T_ref_cam=adj.T_ref_cam.tolist(),
            M_flange_commanded=adj.M_flange_commanded.tolist(),
            clamped=adj.clamped,
            vse_status=state.status,
            vse_points=len(state.cloud),
            alignment_ok=est.ok,
            alignment_reason=est.reason,
            scale=scale,
            sigma=est.T_ref_cur.scale,
            afd_est_px=afd_est,
            truth=evaluate() if evaluate else None,
            estimate_serial=est.serial,
            estimate_vse_frame=est.vse_frame,
            offset_sigma_mm=shared.sigma3d_mm,
            tolerance_mm=shared.tol_mm,
        )
        records.append(rec)
        if on_record:
            on_record(rec)
        if adj.offset_mm > config.max_offset_m * 1e3 or adj.offset_deg > config.max_offset_deg:
            raise AlgorithmError(
                f"the alignment puts the camera {adj.offset_mm:.0f} mm / {adj.offset_deg:.1f} deg from the reference, "
                f"beyond the {config.max_offset_m * 1e3:.0f} mm / {config.max_offset_deg:.0f} deg a revisit starts "
                "within; motion paused (a wrong alignment, or a start far from the reference)"
            )
        # Convergence check (paper §3.7: each adjustment shrinks the offset while the
        # hand-eye rotation error is below 45 deg). An estimate that keeps growing means the
        # estimates or the hand-eye are wrong: stop rather than wander next to the object.
        if best_offset is not None and (
            adj.offset_mm > config.divergence_factor * best_offset[0] + config.divergence_margin_mm
            or adj.offset_deg > config.divergence_factor * best_offset[1] + config.divergence_margin_deg
        ):
            growths += 1
            if growths >= config.divergence_patience:
                raise AlgorithmError(
                    f"relocation is diverging, motion paused: the estimated offset grew to {adj.offset_mm:.1f} mm / "
                    f"{adj.offset_deg:.2f} deg (best {best_offset[0]:.1f} mm / {best_offset[1]:.2f} deg); "
                    "check the hand-eye calibration and the scene (symmetric or flat objects defeat 3D alignment)"
                )
        else:
            growths = 0
        if best_offset is None or adj.offset_mm < best_offset[0]:
            best_offset = (adj.offset_mm, adj.offset_deg)
        # Stop rules (docs/relocation.md, "Stop rules"): the paper's g <= eta or the
        # image-space AFD rule, and in both cases the estimated offset within the tolerance.
        within = adj.offset_mm <= shared.tol_mm
        if adj.g <= config.eta and within:
            result = RelocationResult(True, f"g = {adj.g:.2e} <= eta = {config.eta:.0e}", iteration)
            break
        if rec.afd_est_px <= config.stop_afd_px and within:
            result = RelocationResult(
                True,
                f"estimated AFD {rec.afd_est_px:.2f} px <= {config.stop_afd_px} px and offset "
                f"{adj.offset_mm:.2f} mm <= {shared.tol_mm:.2f} mm (g = {adj.g:.2e})",
                iteration,
            )
            break
        mm_cmd, deg_cmd = pose_distance(np.eye(4), adj.M_flange_commanded)
        _say(session, f"adjustment {iteration}: moving {mm_cmd:.1f} mm / {deg_cmd:.2f} deg")
        session.move_by(adj.M_flange_commanded, progress=(0, session.substeps(adj.M_flange_commanded),
                                                          f"adjustment {iteration}: moving"))
        moved_at_frame = session.vse.latest().frames_processed
        shared.moved_at_frame = moved_at_frame
    else:
        result = RelocationResult(False, f"not converged after {config.max_adjustments} adjustments", config.max_adjustments)
    return result


def run_relocation(
    *,
    session: VseSession,
    reference: ReferenceData,
    ref_index,
    camera,
    scale: float,
    T_flange_cam: np.ndarray,
    init: Sim3,
    config: RelocationConfig = RelocationConfig(),
    evaluate: Callable[[], dict] | None = None,
    on_record: Callable[[AdjustmentRecord], None] | None = None,
    reference_images: dict[str, np.ndarray] | None = None,
    grab_current: Callable[[], np.ndarray] | None = None,
) -> RelocationResult:
    """Drive the camera to the reference pose.

    Parameters
    ----------
    session : VseSession
        A running VSE session (exploration done, scale known).
    reference : ReferenceData
        Reference cloud and camera.
    ref_index : fgcd_cli.alignment.ReferenceIndex
        Search structure over the reference cloud, built once.
    camera : PinholeCamera
        Intrinsics of the current camera.
    scale : float
        Metres per VSE map unit of this session.
    T_flange_cam : (4, 4) ndarray
        Hand-eye (identity for the ``--no-handeye`` variant).
    init : Sim3
        Starting similarity ``T_ref_cur``.
    evaluate : callable, optional
        Evaluation hook (simulation only, outside the algorithm): returns a
        dict of true errors written into each log record.
    on_record : callable, optional
        Called with each record (live display, log file).
    reference_images : dict of name -> (H, W) ndarray, optional
        Undistorted reference images, for the final image stage.
    grab_current : callable() -> (H, W) ndarray, optional
        The current undistorted grey image, for the final image stage.
    """
    t_start = time.monotonic()
    worker: AlignmentWorker | None = None
    records: list[AdjustmentRecord] = []
    result = RelocationResult(False, "not started", 0)
    if config.mode not in ("parallel", "serial"):
        raise AlgorithmError(f"unknown relocation mode {config.mode!r}")
    if config.mode == "parallel":
        worker = AlignmentWorker(
            vse=session.vse,
            scale=scale,
            reference=reference,
            ref_index=ref_index,
            camera=camera,
            init=init,
            fine=config.fine,
            min_points=config.min_points,
        ).start()
    can_image = bool(reference_images) and grab_current is not None
    tol = config.tolerance_mm if config.tolerance_mm is not None else tolerance_mm(
        reference.points, reference.T_ref_camref, camera, stop_afd_px=config.stop_afd_px)
    depth = reference_depth_m(reference.points, reference.T_ref_camref)
    shared = _LoopShared(tol_mm=tol, sigma3d_mm=1000.0 * config.vse_sigma_rel * depth if math.isfinite(depth) else math.inf)

    def fresh_3d(after_frame: int):
        """A trustworthy 3D estimate of a view after ``after_frame``: (T_ref_cam, note) or (None, why)."""
        return _fresh_3d_estimate(session=session, worker=worker, config=config, shared=shared, scale=scale,
                                  reference=reference, ref_index=ref_index, camera=camera, after_frame=after_frame)

    try:
        try:
            result = _racr_loop(session=session, reference=reference, ref_index=ref_index, camera=camera,
                                scale=scale, T_flange_cam=T_flange_cam, init=init, config=config,
                                evaluate=evaluate, on_record=on_record, worker=worker, records=records,
                                t_start=t_start, shared=shared)
        except AlgorithmError as paused:
            # The 3D loop paused (degenerate geometry, too few inliers, divergence). Without
            # the fallback, or when it finds no strong evidence either, the pause stands.
            if not (config.image_fallback and can_image):
                raise
            result = RelocationResult(False, str(paused), len(records))
        if worker is not None and not result.converged:
            worker.stop()  # the 3D estimates are not used any more: free the CPU for matching
            worker = None
        image_kwargs = dict(session=session, reference=reference, camera=camera, scale=scale,
                            T_flange_cam=T_flange_cam, config=config, records=records,
                            reference_images=reference_images, grab_current=grab_current,
                            evaluate=evaluate, on_record=on_record, t_start=t_start, shared=shared,
                            fresh_3d=fresh_3d)
        if result.converged and config.image_refine and can_image:
            result = _image_stage(result=result, fallback=False, **image_kwargs)
        elif not result.converged and config.image_fallback and can_image:
            result = _image_stage(result=result, fallback=True, **image_kwargs)
        elif result.converged and records:
            last = records[-1]
            result.residual = Residual(offset_mm=last.offset_mm, sigma_mm=shared.sigma3d_mm, tolerance_mm=tol,
                                       source="3d", agreement="not checked: no image stage")
            result.reason = f"{result.reason}; {result.residual.text()}"
    finally:
        if worker is not None:
            worker.stop()
    result.records = records
    result.final_T_ref_cam = np.array(records[-1].T_ref_cam) if records else None
    result.wall_s = time.monotonic() - t_start
    result.session_s = session.timing.total_s
    result.platform_s = session.timing.platform_s
    result.synthetic_s = session.timing.synthetic_s
    return result


def _fresh_3d_estimate(*, session, worker, config, shared: _LoopShared, scale, reference, ref_index, camera,
                       after_frame: int):
    """The 3D estimate of the current camera from a view after ``after_frame``.

    Parallel mode waits (at most ``config.agreement_wait_s``) for the alignment thread
    to publish a trustworthy estimate of such a view; serial mode aligns once now,
    from the 3D loop's last estimate.

    Returns
    -------
    T_ref_cam : (4, 4) ndarray or None
        The current camera in the reference frame, or None.
    note : str
        Why there is none (empty when there is one).
    """
    if shared.last_T_ref_cur is None:
        return None, "no trustworthy 3D estimate in this run"
    if config.mode == "parallel":
        if worker is None:
            return None, "the 3D alignment was stopped"
        _say(session, "waiting for a 3D estimate of this view to compare with the image estimate")
        t0 = time.monotonic()
        while time.monotonic() - t0 < config.agreement_wait_s:
            est = worker.latest_ok()
            if worker.error:
                return None, f"alignment thread stopped: {worker.error}"
            if est is not None and est.vse_frame > after_frame:
                break
            time.sleep(0.05)
        else:
            return None, f"no 3D estimate of this view within {config.agreement_wait_s:.0f} s"
        session.timing.wait_s += time.monotonic() - t0
    else:
        _say(session, "aligning the current cloud to compare with the image estimate")
        state = session.tracking_state()
        t0 = time.monotonic()
        ests = align_once(state=state, scale=scale, reference=reference, ref_index=ref_index, camera=camera,
                          init=shared.last_T_ref_cur, fine=config.fine)
        session.timing.wait_s += time.monotonic() - t0
        oks = [e for e in ests if e.ok]
        if not oks:
            return None, f"3D alignment untrustworthy: {ests[-1].reason}"
        est = oks[-1]
    state = session.vse.latest()
    if state.status != "tracking" or state.T_map_cam is None:
        return None, f"the VSE is not tracking ({state.status})"
    from fgcd_cli.relocation.adjustment import camera_in_reference

    return camera_in_reference(est.T_ref_cur, _scaled_pose(state.T_map_cam, scale)), ""


def _image_stage(*, session, reference, camera, scale, T_flange_cam, config, records, result, reference_images,
                 grab_current, evaluate, on_record, t_start, fallback: bool, shared: _LoopShared,
                 fresh_3d) -> RelocationResult:
    """Image-based steps from the reference images (see :mod:`.image_refine`).

    Each step matches the current image with the reference images, solves the
    camera motion by PnP on the reference cloud and moves (through the guard,
    clamped to the largest step). It stops only when the correction moves the
    reference image by less than ``image_stop_afd_px`` *and* the camera offset it
    measures is within the tolerance (:func:`tolerance_mm`); and, after a converged
    3D loop, only when a 3D estimate of the same view agrees with it within their
    uncertainties (:func:`estimates_agree`). Disagreement takes another step;
    running out of steps pauses (not converged) with the reason.

    After a converged 3D loop (``fallback=False``), weak image evidence before any
    image motion leaves the rACR result as it is (the record says why; the residual
    is the 3D estimate's, with its larger uncertainty). When the 3D loop paused
    (``fallback=True``) the image estimate is the only one left.
    """
    from fgcd_cli.geometry.se3 import invert_pose
    from fgcd_cli.relocation.adjustment import clamp_motion
    from fgcd_cli.relocation.image_refine import refine_from_reference_image

    last = records[-1] if records else None
    first_iteration = last.iteration if last is not None else 0
    X = np.asarray(T_flange_cam, dtype=float)
    label = "image fallback" if fallback else "image stage"
    reason = result.reason
    steps = config.image_fallback_steps if fallback else config.image_refine_steps
    tol = shared.tol_mm
    residual: Residual | None = None
    moved = False  # an image motion was made since the last estimate that reached the tolerance
    after_frame = shared.moved_at_frame
    done = False
    for step in range(steps):
        state = session.settle(frames=2)
        _say(session, f"{label} {step + 1}/{steps}: matching the current image with {len(reference_images)} "
                      "reference image(s)")
        t0 = time.monotonic()
        ref = refine_from_reference_image(reference_images=reference_images, current_image=grab_current(),
                                          camera=camera, ref_points=reference.points,
                                          T_ref_camref=reference.T_ref_camref)
        session.timing.wait_s += time.monotonic() - t0
        info = {"matches": ref.matches, "inliers": ref.inliers, "rms_px": ref.rms_px,
                "measured_afd_px": ref.measured_afd_px, "reference_image": ref.reference_image,
                "matcher": ref.matcher, "fallback": fallback}
        sigma = math.nan
        if ref.ok:
            T_ref_cam = np.asarray(reference.T_ref_camref, dtype=float) @ invert_pose(ref.M_cam)
            M_flange = X @ ref.M_cam @ invert_pose(X)
            M_cmd, clamped = clamp_motion(M_flange, max_step_m=config.max_step_m, max_step_rad=config.max_step_rad)
            g = float(np.linalg.norm(M_flange - np.eye(4)))
            off_mm, off_deg = pose_distance(T_ref_cam, reference.T_ref_camref)
            afd = estimated_afd_px(reference.points, reference.T_ref_camref, T_ref_cam, camera)
            sigma = ref.offset_sigma_mm
        elif last is not None:
            T_ref_cam, M_cmd, clamped = np.asarray(last.T_ref_cam), np.eye(4), False
            g, off_mm, off_deg, afd = last.g, last.offset_mm, last.offset_deg, last.afd_est_px
        else:  # nothing is known about the current pose
            T_ref_cam, M_cmd, clamped = np.full((4, 4), np.nan), np.eye(4), False
            g = off_mm = off_deg = afd = math.nan
        within = ref.ok and afd <= config.image_stop_afd_px and off_mm <= tol
        agreement = None
        if within and not fallback:
            agreement = _agreement(fresh_3d, after_frame, T_ref_cam, sigma, reference, shared, config)
        rec = AdjustmentRecord(
            iteration=first_iteration + step + 1, t_wall_s=time.monotonic() - t_start,
            t_session_s=session.timing.total_s, stage="image", g=g, offset_mm=off_mm, offset_deg=off_deg,
            T_ref_cam=np.asarray(T_ref_cam).tolist(), M_flange_commanded=np.asarray(M_cmd).tolist(),
            clamped=clamped, vse_status=state.status, vse_points=len(state.cloud), alignment_ok=ref.ok,
            alignment_reason=ref.reason, scale=scale, sigma=last.sigma if last is not None else math.nan,
            afd_est_px=afd, truth=evaluate() if evaluate else None, image=info,
            offset_sigma_mm=sigma if ref.ok else (last.offset_sigma_mm if last is not None else None),
            tolerance_mm=tol, agreement=agreement,
        )
        records.append(rec)
        if on_record:
            on_record(rec)
        if not ref.ok:
            reason = f"{result.reason}; {label}: {ref.reason}"
            if not fallback and not moved and last is not None:
                # weak evidence before any image motion: the converged 3D result stands
                residual = Residual(offset_mm=last.offset_mm, sigma_mm=shared.sigma3d_mm, tolerance_mm=tol,
                                    source="3d", agreement=f"not checked: {label} declined")
                done = True
            break
        if within and (agreement is None or agreement["agree"] is not False):
            verdict = "not checked" if agreement is None else (
                "agree" if agreement["agree"] else f"not checked: {agreement['note']}")
            if fallback:
                verdict = "not checked: the 3D loop paused"
            residual = Residual(offset_mm=off_mm, sigma_mm=sigma, tolerance_mm=tol, source="image", agreement=verdict)
            reason = (f"{result.reason}; {label}: correction {afd:.2f} px <= {config.image_stop_afd_px} px and "
                      f"{off_mm:.2f} mm <= {tol:.2f} mm")
            done = True
            break
        if within:  # the image says done, the 3D estimate of the same view disagrees: measure again
            reason = (f"{result.reason}; {label}: the 3D and image estimates disagree by "
                      f"{agreement['distance_mm']:.1f} mm (> {agreement['bound_mm']:.1f} mm)")
        else:
            reason = (f"{result.reason}; {label}: after {step + 1} step(s) it still measures {off_mm:.2f} ± "
                      f"{sigma:.2f} mm / {afd:.2f} px (tolerance {tol:.2f} mm, {config.image_stop_afd_px} px)")
        _say(session, f"{label} {step + 1}/{steps}: moving {off_mm:.1f} mm / {off_deg:.2f} deg")
        session.move_by(M_cmd, progress=(0, session.substeps(M_cmd), f"{label} {step + 1}: moving"))
        moved = True
        after_frame = session.vse.latest().frames_processed
    if done and residual is not None:
        out = RelocationResult(True, f"{reason}; {residual.text()}", records[-1].iteration)
        out.residual = residual
        return out
    # Out of steps, or the image evidence failed after an image motion: the remaining
    # offset is not known to be within the tolerance. Never "converged" on that.
    if not fallback:
        out = RelocationResult(False, f"motion paused: {reason}", records[-1].iteration if records else 0)
        last_rec = records[-1] if records else None
        if last_rec is not None and last_rec.alignment_ok:
            out.residual = Residual(offset_mm=last_rec.offset_mm, sigma_mm=float(last_rec.offset_sigma_mm or math.nan),
                                    tolerance_mm=tol, source="image", agreement="not checked")
        return out
    raise AlgorithmError(f"motion paused: {reason}")


def _agreement(fresh_3d, after_frame: int, T_ref_cam_img: np.ndarray, sigma_img_mm: float, reference,
               shared: _LoopShared, config: RelocationConfig) -> dict:
    """Compare the image estimate with a 3D estimate of the same view (:func:`estimates_agree`).

    Returns a dict for the log: ``agree`` (True, False, or None when no 3D estimate
    of this view was available), the distance and bound in mm, the 3D offset, a note.
    """
    T_3d, note = fresh_3d(after_frame)
    if T_3d is None:
        return {"agree": None, "note": note}
    d_img = _offset_vector_mm(T_ref_cam_img, reference.T_ref_camref)
    d_3d = _offset_vector_mm(T_3d, reference.T_ref_camref)
    ok, dist, bound = estimates_agree(d_img, sigma_img_mm, d_3d, shared.sigma3d_mm, k=config.agreement_k)
    return {"agree": ok, "distance_mm": dist, "bound_mm": bound, "offset_3d_mm": float(np.linalg.norm(d_3d)),
            "sigma_3d_mm": shared.sigma3d_mm, "note": ""}


def _wait_for_estimate(worker: AlignmentWorker, last_serial: int, config: RelocationConfig, session: VseSession) -> AlignmentEstimate:
    """The newest alignment published after ``last_serial``; pause on failures."""
    t0 = time.monotonic()
    seen_bad: set[int] = set()  # serials of untrustworthy estimates since we started waiting
    seen_degenerate: set[int] = set()  # ... of those flagged degenerate geometry
    next_note = t0 + HEARTBEAT_S
    while True:
        if time.monotonic() >= next_note:  # never silent for long (issue 24, item 7)
            est = worker.latest()
            _say(session, f"  still aligning ({time.monotonic() - t0:.0f} s; latest estimate: "
                          + ("none yet" if est is None else f"{est.stage}, {'ok' if est.ok else est.reason}") + ")")
            next_note += HEARTBEAT_S
        if worker.error:
            raise AlgorithmError(f"alignment thread stopped: {worker.error}")
        est = worker.latest()
        if est is not None and est.serial > last_serial and est.ok:
            session.timing.wait_s += time.monotonic() - t0
            return est
        waited = time.monotonic() - t0
        if est is not None and est.serial > last_serial and not est.ok:
            seen_bad.add(est.serial)
            if est.degenerate:
                seen_degenerate.add(est.serial)
            else:
                seen_degenerate.clear()
            if len(seen_degenerate) >= config.degenerate_patience:
                session.timing.wait_s += waited
                raise AlgorithmError(f"alignment found degenerate geometry in {len(seen_degenerate)} estimates in a "
                                     f"row ({waited:.0f} s), motion paused: {est.reason}")
            if len(seen_bad) >= config.untrusted_patience and waited >= config.untrusted_min_wait_s:
                session.timing.wait_s += waited
                raise AlgorithmError(f"alignment untrustworthy in {len(seen_bad)} estimates in a row "
                                     f"({waited:.0f} s), motion paused: {est.reason}")
        if waited > config.estimate_timeout_s:
            session.timing.wait_s += waited
            why = est.reason if est is not None else "no estimate yet"
            raise AlgorithmError(f"no trustworthy alignment within {config.estimate_timeout_s:.0f} s, motion paused: {why}")
        time.sleep(0.01)


def estimated_afd_px(
    ref_points: np.ndarray, T_ref_camref: np.ndarray, T_ref_cam: np.ndarray, camera, *, max_points: int = 3000
) -> float:
    """Mean image displacement (px) between the reference camera and the estimated current one.

    The reference points seen by the reference camera are projected into both
    cameras; the mean distance between the two projections is the AFD the
    remaining offset would produce, as far as the estimate knows.
    """
    from fgcd_cli.geometry.se3 import invert_pose, transform_points

    P = np.asarray(ref_points, dtype=float)
    if len(P) > max_points:
        P = P[np.linspace(0, len(P) - 1, max_points).astype(int)]
    if camera is None or len(P) == 0:
        return float("inf")
    uv_ref, ok_ref = camera.project(transform_points(invert_pose(T_ref_camref), P))
    uv_cur, ok_cur = camera.project(transform_points(invert_pose(T_ref_cam), P))
    ok = ok_ref & np.isfinite(uv_cur).all(axis=1)
    if not np.any(ok):
        return float("inf")
    return float(np.mean(np.linalg.norm(uv_cur[ok] - uv_ref[ok], axis=1)))


def offset_to_reference(T_ref_cam: np.ndarray, T_ref_camref: np.ndarray) -> tuple[float, float]:
    """Remaining offset in mm and degrees (for displays)."""
    return pose_distance(T_ref_cam, T_ref_camref)
