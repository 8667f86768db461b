"""The rig lamp's own image (flash / no-flash) on a reference and on its visits.

A reference taken under the day's light cannot be lit again: no rig moves the
sun. The lamp at the lens can: its image alone (a still with it on minus one
with it off, at one exposure: ``fgcd_core.flash``) is the same on every visit
at the same pose, noon or night. The capture stores it as the image
``flash:<lamp>`` where the day's light is part of the reference; a visit of such
a reference takes it again, the final image stage measures on it and the
change map compares it like with like (docs/relocation.md, "The lamp's own image").

A reference taken in a dark world (a closed room, the night) records the lamp's
share of its light (``lamp_share`` in its metadata): its lamp images *are* the
lamps alone. A visit of it under the day's light measures on the lamp's own image
taken now against the reference's plain lamp image (:func:`lamp_alone_now`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgcd_cli.errors import AlgorithmError
from fgcd_core.flash import LampOnlyImage, lamp_only_image
from fgcd_core.imaging import to_float01
from fgcd_drivers.lights import AMBIENT

__all__ = [
    "FLASH_LAMP",
    "FLASH_PREFIX",
    "MIN_LAMP_SHARE",
    "DARK_WORLD_LAMP_SHARE",
    "LAMP_SHARE_KEY",
    "ReferenceLamp",
    "dark_world",
    "flash_name",
    "flash_lamp",
    "lamp_alone_now",
    "can_flash",
    "grab_flash",
    "mean_still",
    "reference_flash",
]

#: The rig lamp whose own image is taken: the lamp at the lens (a ring light or a flash), channel ``front``.
FLASH_LAMP = "front"

#: Image names of a lamp's own image: ``flash:front``.
FLASH_PREFIX = "flash:"

#: Below this share of the lit still the lamp's image is too faint to measure on. Model: an 8-bit
#: still at the median grey (0.18 linear) has about 0.003 linear of noise and quantisation; the
#: difference of two 2-still means about 0.003; a 10 % share (0.018) is then 6 sigma above it.
MIN_LAMP_SHARE = 0.10

#: Above this share the day adds under 5 % to the lamp: the world is dark (a closed room, the night),
#: the reference's lamp images repeat as they are, and no separate lamp-only image is stored.
DARK_WORLD_LAMP_SHARE = 0.95

#: Metadata key of a reference: the share of :data:`FLASH_LAMP` in its light, where the capture measured it.
LAMP_SHARE_KEY = "lamp_share"


def dark_world(metadata: dict) -> bool:
    """Whether a reference with ``metadata`` was taken in a dark world: its lamp images are the lamps alone."""
    share = metadata.get(LAMP_SHARE_KEY)
    return share is not None and float(share) > DARK_WORLD_LAMP_SHARE


def flash_name(lamp: str = FLASH_LAMP) -> str:
    """The image name of ``lamp``'s own image (``flash:front``)."""
    return f"{FLASH_PREFIX}{lamp}"


def flash_lamp(name: str) -> str | None:
    """The lamp of a lamp-only image name (``flash:front`` -> ``front``), None for any other name."""
    return name[len(FLASH_PREFIX) :] if name.startswith(FLASH_PREFIX) else None


def can_flash(rig, lamp: str = FLASH_LAMP) -> bool:
    """Whether ``rig`` can take ``lamp``'s own image: it carries the lamp and its camera locks its exposure."""
    lights = getattr(rig, "lights", None)  # a rig without switchable lights may not carry the attribute
    camera = getattr(rig, "camera_source", None)
    return lights is not None and lamp in lights.available() and hasattr(camera, "exposure_locked")


def mean_still(camera, count: int) -> np.ndarray:
    """The mean of ``count`` stills (noise) (grey, or colour where the camera gives colour), float64 in [0, 1]."""
    acc = None
    for _ in range(max(1, count)):
        frame = camera.grab_still()
        img = frame.rgb if getattr(frame, "rgb", None) is not None else frame.image
        img = to_float01(np.asarray(img)).astype(np.float64)
        acc = img if acc is None else acc + img
    return acc / max(1, count)


def grab_flash(rig, lamp: str = FLASH_LAMP, *, average: int = 2) -> LampOnlyImage:
    """``lamp``'s own image at the current pose: lamp on, exposure locked, lamp off; lights restored after.

    The exposure is the one the lamp-lit still calls for, so neither still clips more than
    the lit one. Raises :class:`AlgorithmError` when the difference holds no light of the lamp.
    """
    lights, camera = rig.lights, rig.camera_source
    previous = lights.current
    try:
        lights.set(lamp)
        camera.grab_still()  # the automatic exposure settles on the lamp-lit scene
        with camera.exposure_locked():
            lit = mean_still(camera, average)
            lights.set(AMBIENT)
            unlit = mean_still(camera, average)
    finally:
        lights.set(previous if previous in lights.available() else AMBIENT)
    try:
        return lamp_only_image(lit, unlit)
    except ValueError as exc:
        raise AlgorithmError(f"no image of the lamp '{lamp}' alone: {exc}") from None


@dataclass(frozen=True)
class ReferenceLamp:
    """What a capture adds for the lamp: the lamp's own image where it is stored, and the lamp's measured share."""

    images: dict[str, np.ndarray] = field(default_factory=dict)
    """``{flash_name(): image}`` where the image is stored, else empty."""
    metadata: dict = field(default_factory=dict)
    """``{LAMP_SHARE_KEY: share}`` where the share was measured, else empty."""


def reference_flash(rig, say=None) -> ReferenceLamp:
    """The lamp's own image a reference stores (with its name), and the lamp's share of the light.

    Taken where the rig can (:func:`can_flash`); the image is kept where the day's light is
    part of the reference (the lamp's share at most :data:`DARK_WORLD_LAMP_SHARE`) and the
    lamp is bright enough to measure on (share at least :data:`MIN_LAMP_SHARE`). The share is
    recorded whenever it was measured: a dark world's lamp images are the lamps alone
    (:func:`dark_world`). ``say`` gets one line on what was decided.
    """
    say = say or (lambda text: None)
    if not can_flash(rig):
        return ReferenceLamp()
    try:
        got = grab_flash(rig, average=4)  # as many stills as each reference image (app/session.grab_images)
    except AlgorithmError as exc:  # a lamp that adds nothing must not cost the reference
        say(f"{exc}: no image of the lamp alone; revisits measure across lightings")
        return ReferenceLamp()
    share = {LAMP_SHARE_KEY: round(float(got.lamp_share), 4)}
    if got.lamp_share > DARK_WORLD_LAMP_SHARE:
        say(f"the day adds {100 * (1 - got.lamp_share):.0f} % to the lamp's light: its images are the lamps alone")
        return ReferenceLamp(metadata=share)
    if got.lamp_share < MIN_LAMP_SHARE:
        say(
            f"the lamp '{FLASH_LAMP}' adds only {100 * got.lamp_share:.0f} % to the day's light "
            f"(under {100 * MIN_LAMP_SHARE:.0f} %): no image of the lamp alone; revisits measure across lightings"
        )
        return ReferenceLamp(metadata=share)
    say(f"the lamp '{FLASH_LAMP}' alone: {100 * got.lamp_share:.0f} % of the light (image {flash_name()})")
    return ReferenceLamp(images={flash_name(): got.image}, metadata=share)


def lamp_alone_now(rig, vse, reference_metadata: dict, lighting: str | None, say=None) -> str | None:
    """The lamp's own image to measure on instead of ``lighting``, where the reference's world was dark and
    the visit's is not; None: measure under ``lighting`` as it is.

    A dark-world reference's image under a rig lamp is that lamp alone (:func:`dark_world`). Under
    the day's light the same lamp now adds the day to it; its own image (:func:`grab_flash`) does not.
    One lamp image taken now (the VSE held meanwhile) tells whether the day adds light: above
    :data:`DARK_WORLD_LAMP_SHARE` the world is dark now too and nothing changes.
    """
    say = say or (lambda text: None)
    if lighting is None or flash_lamp(lighting) is not None or not dark_world(reference_metadata):
        return None
    if not can_flash(rig, lighting):
        return None
    try:
        with vse.held():
            got = grab_flash(rig, lighting)
    except AlgorithmError as exc:
        say(f"{exc}: the image stage measures under {lighting} with the day's light in it")
        return None
    if got.lamp_share > DARK_WORLD_LAMP_SHARE:
        return None
    name = flash_name(lighting)
    say(
        f"the reference's world was dark and the day now adds {100 * (1 - got.lamp_share):.0f} % to the "
        f"lamp '{lighting}': the image stage measures on its own image ({name}) against the reference's {lighting} image"
    )
    return name
