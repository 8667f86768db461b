"""The scene uncertainty map of a station's reference observation (paper 001, Eq. 2), computed once and cached.

The map depends only on the reference observation, the camera and the options, so it is
computed once: by the capture use case after the reference is written (the demo too), or, for a
station captured before, the first time a relocation needs it (the coarse stage's first look); kept
beside the reference observation as ``scene_uncertainty-<key>.npz``, ``key`` naming the
reference, the intrinsics and the options: another reference or camera gets its own file, and
an existing file is never written over. The reference observation itself is immutable.
Campaigns without the file keep working: it is computed when first needed.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np

from fgcd_cli.campaign import schema
from fgcd_cli.campaign.atomic import atomic_write_bytes, sha256_bytes
from fgcd_cli.errors import FgcdError
from fgcd_cli.relocation.coarse.config import CoarseConfig
from fgcd_cli.relocation.coarse.scene_uncertainty import (
    SceneUncertaintyConfig,
    SceneUncertaintyMap,
    build_scene_model,
    scene_uncertainty_map,
)

__all__ = ["cached_scene_uncertainty", "scene_uncertainty_path", "station_scene_uncertainty"]


def scene_uncertainty_path(
    station, camera, *, config: SceneUncertaintyConfig = SceneUncertaintyConfig(), coarse: CoarseConfig = CoarseConfig()
) -> Path:
    """Where the station's map for this reference, camera and options is cached."""
    reference = station.reference()
    key = json.dumps(
        {
            "reference": reference.manifest,
            "camera": camera.to_dict(),
            "options": asdict(config),
            "coarse": [coarse.sigma_rel, coarse.verify_m, coarse.verify_deg, coarse.weak_ratio],
        },
        sort_keys=True,
        default=str,
    )
    return Path(station.path) / f"{schema.SCENE_UNCERTAINTY_PREFIX}-{sha256_bytes(key.encode())[:16]}.npz"


def station_scene_uncertainty(
    station,
    camera,
    *,
    config: SceneUncertaintyConfig = SceneUncertaintyConfig(),
    coarse: CoarseConfig = CoarseConfig(),
    say: Callable[[str], None] = lambda _m: None,
) -> SceneUncertaintyMap | None:
    """The station's scene uncertainty map: read from its cache, or computed and cached.

    Parameters
    ----------
    station : Station
        Whose reference observation (cloud, camera pose, images) the map is computed from.
    camera : PinholeCamera
        The rig's undistorted intrinsics.
    config : SceneUncertaintyConfig
    coarse : CoarseConfig
        The verification limits and covariance model of the coarse stage.
    say : callable(str)

    Returns
    -------
    SceneUncertaintyMap or None
        None when the reference cannot give one (no cloud, no images); the reason is said.
    """
    from fgcd_cli.app.session import load_reference, reference_images
    from fgcd_cli.relocation.image.refine import reference_keypoints_3d

    path = scene_uncertainty_path(station, camera, config=config, coarse=coarse)
    if path.exists():
        return SceneUncertaintyMap.from_npz(path.read_bytes())
    try:
        reference = load_reference(station)
        keypoints = reference_keypoints_3d(
            reference_images=reference_images(station),
            camera=camera,
            ref_points=reference.points,
            T_ref_camref=reference.T_ref_camref,
        )
        model = build_scene_model(
            reference_points=reference.points,
            T_ref_camref=reference.T_ref_camref,
            camera=camera,
            keypoints_per_image=keypoints,
            config=config,
        )
        smap = scene_uncertainty_map(model, camera, config=config, coarse=coarse)
    except (FgcdError, KeyError, ValueError, OSError, np.linalg.LinAlgError) as exc:
        # guidance only: a reference that cannot give a map leaves the looks in their fixed order
        say(f"no scene uncertainty map ({exc}); the looks keep their fixed order")
        return None
    say(f"scene uncertainty map computed in {smap.seconds:.1f} s")
    if not path.exists():  # never over an earlier file
        try:
            atomic_write_bytes(path, smap.to_npz())
        except OSError as exc:
            say(f"scene uncertainty map not cached ({exc})")
    return smap


def cached_scene_uncertainty(station) -> SceneUncertaintyMap | None:
    """The station's most recently cached scene uncertainty map, or None (nothing is computed)."""
    files = sorted(Path(station.path).glob(f"{schema.SCENE_UNCERTAINTY_PREFIX}-*.npz"), key=lambda p: p.stat().st_mtime)
    return SceneUncertaintyMap.from_npz(files[-1].read_bytes()) if files else None
