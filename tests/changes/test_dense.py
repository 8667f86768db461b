"""Dense refinement after the homography: removes smooth parallax, keeps real changes, flags what it cannot align."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from fgcd_cli.changes.dense.fit import smoothing_scale_px
from fgcd_cli.changes.dense.refine import DenseConfig, apply_flow, lighting_invariant, refine_dense, warp_with_flow
from fgcd_cli.changes.images import to_float_image, to_gray
from fgcd_cli.changes.registration import gradient_magnitude, register_to_reference, warp_to_reference

from .conftest import textured_scene

SIZE = 384
BUMP_PX = 3.0
"""Peak of the synthetic parallax, px (the residual parallax of a relief is 0.5-5 px)."""
BUMP_SIGMA_PX = 90.0
"""Gaussian width of the synthetic parallax bump, px: smooth over tens of pixels."""
DATASET = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "fgcd-dataset"


def _gain(size: int = SIZE) -> np.ndarray:
    """Lighting gain of the second visit: a ramp 0.7..1.2 across the image (1xW float32)."""
    return np.linspace(0.7, 1.2, size, dtype=np.float32)[None, :]


def _parallax(x: np.ndarray, y: np.ndarray, size: int = SIZE) -> tuple[np.ndarray, np.ndarray]:
    """True flow at reference pixel (x, y): a bump of BUMP_PX, pointing along (0.8, 0.6)."""
    cx, cy = 0.55 * size, 0.45 * size
    m = BUMP_PX * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2.0 * BUMP_SIGMA_PX**2))
    return 0.8 * m, 0.6 * m


def _render_current(scene: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Current image of ``scene`` (reference frame) under the parallax, with the gain ramp.

    Scene point x appears at x + P(x). The inverse map y -> x = y + Q(y) solves
    Q(y) = -P(y + Q(y)) by fixed-point iteration on the analytic P (contraction:
    |grad P| < 0.03). Returns the current image and the true flow P (HxWx2).
    """
    h, w = scene.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    qx, qy = np.zeros_like(xs), np.zeros_like(ys)
    for _ in range(30):
        px, py = _parallax(xs + qx, ys + qy, w)
        qx, qy = -px, -py
    cur = cv2.remap(
        scene.astype(np.float32),
        (xs + qx).astype(np.float32),
        (ys + qy).astype(np.float32),
        cv2.INTER_CUBIC,
        borderMode=cv2.BORDER_REFLECT,
    )
    truth = np.stack(_parallax(xs, ys, w), axis=2).astype(np.float32)
    return np.clip(cur * _gain(w), 0.0, 1.0), truth


def _disc(size: int, cx: int, cy: int, radius: int) -> np.ndarray:
    mask = np.zeros((size, size), np.uint8)
    cv2.circle(mask, (cx, cy), radius, 1, -1)
    return mask.astype(bool)


def _interior(size: int = SIZE, margin: int = 16) -> np.ndarray:
    inner = np.zeros((size, size), bool)
    inner[margin:-margin, margin:-margin] = True
    return inner


def _peak_bias_px(smooth_px: float) -> float:
    """Bias of the local-quadratic fit at the bump's peak, px.

    The fit's equivalent kernel is ``g(r) (2 - r^2 / (2 s^2))`` (g Gaussian of scale s);
    on a Gaussian bump of scale b it returns ``(1 + 2t) / (1 + t)^2`` of the peak, t = s^2/b^2.
    """
    t = (smooth_px / BUMP_SIGMA_PX) ** 2
    return BUMP_PX * (1.0 - (1.0 + 2.0 * t) / (1.0 + t) ** 2)


def _raw_dis(ref: np.ndarray, cur: np.ndarray) -> np.ndarray:
    """Unregularised DIS flow on the same lighting-invariant images (what the refinement must not be)."""
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    return dis.calc(lighting_invariant(ref), lighting_invariant(cur), None)


def test_smoothing_scale_follows_the_change_model():
    # 60 px change, 25 % share: 39.6 px for a local constant/linear fit, 57 px for a quadratic.
    assert smoothing_scale_px(60.0, share=0.25, order=1) == pytest.approx(39.55, abs=0.05)
    assert smoothing_scale_px(60.0, share=0.25, order=2) == pytest.approx(57.0, abs=0.1)
    # Keeping larger changes needs a larger window, proportionally.
    assert smoothing_scale_px(120.0) == pytest.approx(2.0 * smoothing_scale_px(60.0))


def test_smooth_parallax_is_removed_under_a_gain_change():
    ref = textured_scene(SIZE)
    cur, truth = _render_current(ref)
    gain = _gain()
    result = refine_dense(ref, cur)
    inner = _interior()

    grad_ref = gradient_magnitude(ref)
    residual = lambda image: float(np.abs(grad_ref - gradient_magnitude(image / gain))[inner].mean())  # noqa: E731
    before = residual(cur)
    after = residual(apply_flow(cur, result.flow))
    floor = residual(apply_flow(cur, truth))  # resampling blur: what even the true flow leaves
    # Mean flow error before is ~1.3 px, after ~0.1 px; the misalignment part of the
    # gradient residual scales with it (~10x): 4x leaves margin for the resampling noise.
    assert before - floor > 4.0 * (after - floor), (before, after, floor)

    error = np.hypot(*(result.flow - truth).transpose(2, 0, 1))
    confident = (result.confidence > 0.5) & inner
    assert confident.mean() > 0.8  # textured everywhere: nearly all of it is confident
    assert float(error[confident].mean()) < 0.15
    assert float(np.percentile(error[confident], 95)) < 0.3
    # The largest error sits on the bump's peak: the fit's known bias there, plus DIS noise.
    assert float(error[inner].max()) < _peak_bias_px(result.settings["smooth_px"]) + 0.15
    assert result.not_compared[inner].mean() < 0.01


def test_blobs_survive_the_flow():
    ref = textured_scene(SIZE)
    scene = ref.copy()
    dark = _disc(SIZE, 190, 230, 12)  # 25 px loss on the bump's flank, where the parallax varies most
    bright = _disc(SIZE, 250, 110, 20)  # 40 px bright stain
    scene[dark] = 0.05
    scene[bright] = 0.95
    cur, truth = _render_current(scene)
    gain = _gain()
    result = refine_dense(ref, cur)
    aligned = apply_flow(cur, result.flow) / gain
    ideal = apply_flow(cur, truth) / gain
    for blob in (dark, bright):
        kept = np.abs(ref - aligned)[blob].mean() / np.abs(ref - ideal)[blob].mean()
        assert kept >= 0.8, kept
    # The field there stays the parallax's: no bend towards the blobs.
    error = np.hypot(*(result.flow - truth).transpose(2, 0, 1))
    assert float(error[dark | bright].max()) < _peak_bias_px(result.settings["smooth_px"]) + 0.15
    # A change is compared (flagged as change later), not hidden as "not compared".
    assert not result.not_compared[dark | bright].any()


def test_a_growing_loss_is_not_shrunk_back():
    """Losses that grew between visits look like local expansion: raw optical flow undoes them."""
    ref = textured_scene(SIZE)
    scene = ref.copy()
    change = np.zeros((SIZE, SIZE), bool)
    for cx, cy, radius, growth, level in [(100, 100, 12, 5, 0.08), (250, 120, 20, 6, 0.9), (120, 270, 8, 4, 0.1)]:
        ref[_disc(SIZE, cx, cy, radius)] = level
        scene[_disc(SIZE, cx, cy, radius + growth)] = level
        change |= _disc(SIZE, cx, cy, radius + growth) & ~_disc(SIZE, cx, cy, radius)
    cur, truth = _render_current(scene)
    gain = _gain()
    labels = cv2.connectedComponents(change.astype(np.uint8))[1]

    def kept(flow: np.ndarray) -> list[float]:
        diff = np.abs(ref - apply_flow(cur, flow) / gain)
        ideal = np.abs(ref - apply_flow(cur, truth) / gain)
        return [float(diff[labels == i].mean() / ideal[labels == i].mean()) for i in range(1, labels.max() + 1)]

    # The case is a real trap: unregularised DIS erases about half of the largest ring.
    assert min(kept(_raw_dis(ref, cur))) < 0.6
    result = refine_dense(ref, cur)
    assert min(kept(result.flow)) >= 0.9
    assert not result.not_compared[change].any()


def test_matches_stay_consistent_under_a_blotchy_light():
    """A gain varying over ~15 px (x1.65 per standard deviation): light through foliage, uneven lamps."""
    ref = textured_scene(SIZE)
    cur, truth = _render_current(ref)
    noise = np.random.default_rng(1).standard_normal((SIZE, SIZE)).astype(np.float32)
    field = cv2.GaussianBlur(noise, (0, 0), 15.0)
    gain = np.exp(0.5 * field / field.std())
    cur = np.clip(cur / _gain() * gain / gain.max(), 0.0, 1.0)
    result = refine_dense(ref, cur)
    inner = _interior()
    # On contrast-normalised log images the matches keep their forward-backward consistency
    # (mean confidence 0.94 measured; on raw intensities DIS's patch-mean normalisation
    # alone leaves 0.48): the gain cancels instead of looking like structure.
    assert float(result.confidence[inner].mean()) > 0.8
    error = np.hypot(*(result.flow - truth).transpose(2, 0, 1))
    assert float(error[inner].mean()) < 0.15


def test_identity_pair_gives_zero_flow():
    ref = textured_scene(SIZE)
    cur = np.clip(ref * _gain(), 0.0, 1.0)  # same view, different exposure
    result = refine_dense(ref, cur)
    rms = float(np.sqrt((result.flow**2).sum(axis=2).mean()))
    assert rms < 0.1
    assert not result.not_compared[_interior()].any()
    assert result.flow.shape == (SIZE, SIZE, 2) and result.flow.dtype == np.float32
    assert result.confidence.dtype == np.float32
    assert 0.0 <= result.confidence.min() and result.confidence.max() <= 1.0


def test_occlusion_gets_low_confidence_not_a_wild_flow():
    ref = textured_scene(SIZE)
    cur, truth = _render_current(ref)
    # An 80 px patch of unrelated texture (another part of the image, rotated) covers the view.
    y0, x0 = 150, 200
    cur[y0 : y0 + 80, x0 : x0 + 80] = np.rot90(ref[20:100, 280:360]) * _gain()[:, x0 : x0 + 80]
    occluded = np.zeros((SIZE, SIZE), bool)
    occluded[y0 : y0 + 80, x0 : x0 + 80] = True
    error_raw = np.hypot(*(_raw_dis(ref, cur) - truth).transpose(2, 0, 1))
    assert np.percentile(error_raw[occluded], 90) > 2.0  # raw matching there is wild

    result = refine_dense(ref, cur)
    error = np.hypot(*(result.flow - truth).transpose(2, 0, 1))
    # The smooth field crosses the patch from its surroundings: within half a pixel (the
    # bump's peak, 0.25 px of known bias, lies inside the patch), where raw DIS is off by > 2 px.
    assert float(error[occluded].max()) < 0.5
    trusted = result.confidence > 0.5
    outside = _interior() & ~cv2.dilate(occluded.astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool)
    low = ~trusted | result.not_compared
    assert low[occluded].mean() > 0.7
    assert low[outside].mean() < 0.1


def test_flow_beyond_the_cap_is_not_compared():
    ref = textured_scene(SIZE)
    M = np.float32([[1, 0, 7.0], [0, 1, 0]])  # content moves right: ref pixel x seen at x + 7
    cur = cv2.warpAffine(ref, M, (SIZE, SIZE), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    result = refine_dense(ref, cur, config=DenseConfig(max_flow_px=5.0))
    inner = _interior()
    assert result.not_compared[inner].mean() > 0.95
    assert float(result.magnitude.max()) <= 5.0 + 1e-4  # clipped: nothing wild reaches the resampling
    relaxed = refine_dense(ref, cur, config=DenseConfig(max_flow_px=10.0))
    assert relaxed.not_compared[inner].mean() < 0.01
    assert np.abs(relaxed.flow[inner][:, 0] - 7.0).mean() < 0.1


def test_apply_flow_and_single_resampling():
    rng = np.random.default_rng(0)
    image = rng.random((40, 50, 3)).astype(np.float32)
    flow = np.zeros((40, 50, 2), np.float32)
    flow[..., 0] = 1.0  # out(x, y) = image(x + 1, y)
    out = apply_flow(image, flow)
    assert out.shape == image.shape and out.dtype == np.float32
    np.testing.assert_allclose(out[:, :-1], image[:, 1:], atol=1e-5)
    wide = rng.random((40, 50, 6)).astype(np.float32)
    np.testing.assert_allclose(apply_flow(wide, flow)[:, :-1], wide[:, 1:], atol=1e-5)

    # warp_with_flow = warp_to_reference then apply_flow, in one interpolation. Bilinear
    # resampling is exact on linear images: the current image's own coordinates come back
    # as the composed map x -> H (x + flow), up to OpenCV's 1/32 px quantisation of the
    # sub-pixel position (INTER_TAB_SIZE) in remap and warpPerspective.
    h, w = 100, 120
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    coords = np.stack([xs, ys], axis=2)
    H = np.array([[1.0, 0.01, 2.5], [-0.01, 1.0, -1.5], [0.0, 0.0, 1.0]])
    flow = np.stack([0.5 + 0.01 * xs, -0.3 + 0.0 * ys], axis=2).astype(np.float32)
    once, valid = warp_with_flow(coords, H, flow)
    twice = apply_flow(warp_to_reference(coords, H, (h, w))[0], flow)
    mapped = np.stack([xs + flow[..., 0], ys + flow[..., 1], np.ones_like(xs)], axis=2) @ H.T
    expected = mapped[..., :2] / mapped[..., 2:]
    inner = np.pad(np.ones((h - 20, w - 20), bool), 10)
    np.testing.assert_allclose(once[inner], expected[inner], atol=1 / 32)
    np.testing.assert_allclose(twice[inner], expected[inner], atol=2 / 32)
    assert valid[inner].all() and not valid.all()


def _real_pair(group: str) -> dict:
    folder = DATASET / group
    read = lambda name: to_gray(to_float_image(cv2.imread(str(folder / name))[:, :, ::-1]))  # noqa: E731
    ref, cur = read("2-1.png"), read("1-1.png")  # GT is aligned with observation 2: the reference
    registration = register_to_reference(ref, cur)
    assert registration.ok, registration.reason
    warped, valid = warp_to_reference(cur, registration.H_cur_ref, ref.shape)
    truth = cv2.imread(str(folder / "GT.png"), cv2.IMREAD_GRAYSCALE) > 127
    mask = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_GRAYSCALE) > 127
    return {
        "ref": ref,
        "cur": cur,
        "warped": warped,
        "valid": valid,
        "truth": truth,
        "mask": mask,
        "H": registration.H_cur_ref,
    }


def _gradient_residuals(pair: dict, result) -> tuple[float, float, float, float]:
    """Mean |gradient difference| outside and inside GT (within mask, compared pixels), before/after."""
    grad_ref = gradient_magnitude(pair["ref"])
    before = np.abs(grad_ref - gradient_magnitude(pair["warped"]))
    refined, seen = warp_with_flow(pair["cur"], pair["H"], result.flow)
    after = np.abs(grad_ref - gradient_magnitude(refined))
    compared = pair["mask"] & pair["valid"] & seen & ~result.not_compared
    background = compared & ~pair["truth"]
    change = compared & pair["truth"]
    return (
        float(before[background].mean()),
        float(after[background].mean()),
        float(before[change].mean()),
        float(after[change].mean()),
    )


@pytest.mark.skipif(
    not (DATASET / "Ds" / "Ds-1").is_dir(), reason=f"real FGCD dataset not found at {DATASET.resolve()}"
)
def test_statue_is_not_made_worse():
    """Ds-1: the homography already fits the statue (raw residual flow p95 0.2 px): nothing to gain, nothing to lose.

    The background plane sits ~2 px off the statue's homography; passing the evaluation
    mask keeps that other depth layer out of the fit.
    """
    pair = _real_pair("Ds/Ds-1")
    result = refine_dense(pair["ref"], pair["warped"], valid=pair["valid"] & pair["mask"])
    inside = pair["mask"] & pair["valid"]
    assert result.not_compared[inside].mean() < 0.02  # measured 0.4 % (the mask's rim)
    assert float(np.percentile(result.magnitude[inside], 95)) < 0.5  # measured 0.13 px
    before, after, change_before, change_after = _gradient_residuals(pair, result)
    # Measured 2.64 -> 2.58 (x1.02); resampling twice (apply_flow after the warp) gives 2.74 (x0.96).
    assert after < 1.01 * before, (before, after)
    assert change_after > 0.95 * change_before


@pytest.mark.skipif(
    not (DATASET / "Dp" / "Dp-1").is_dir(), reason=f"real FGCD dataset not found at {DATASET.resolve()}"
)
def test_relief_parallax_is_removed_and_changes_kept():
    """Dp-1: an outdoor relief with real parallax (residual flow up to 7 px at the left border)."""
    pair = _real_pair("Dp/Dp-1")
    result = refine_dense(pair["ref"], pair["warped"], valid=pair["valid"])
    before, after, change_before, change_after = _gradient_residuals(pair, result)
    # Measured 5.75 -> 3.54 (x1.62) outside the changes, 22.4 -> 22.0 (x1.02) on them:
    # the parallax goes, the changes stay. 1.4 and 0.9 leave ~15 % and ~10 % margin.
    assert before > 1.4 * after, (before, after)
    assert change_after > 0.9 * change_before, (change_before, change_after)
    # Only the left border, where the parallax exceeds the 5 px cap, is not compared (measured 5.7 %).
    inside = pair["mask"] & pair["valid"]
    assert result.not_compared[inside].mean() < 0.1
