"""A visit's change map scored against the simulator's truth (evaluation only: the demo and the benches).

The tool never sees this truth: it is rendered here, after the diff, from the
simulated world the visit was made in (:mod:`fgcd_cli.metrics.sim_eval`).
"""

from __future__ import annotations

import numpy as np

from fgcd_cli.campaign import schema
from fgcd_cli.metrics.sim_eval import change_ids_in_reference, count_changes_found, score_change_detection

__all__ = ["score_visit_changes"]


def score_visit_changes(visit, station, *, scenario, X: np.ndarray, camera, injected: int) -> dict:
    """Pixel scores (F1, precision, recall, false regions) and changes found, of the visit's change mask.

    Parameters
    ----------
    visit, station : campaign observation and station
        The diffed visit (its ``changes/`` products) and its station (the reference's truth pose).
    scenario : SimScenario
        The world of the visit, with its injected changes.
    X : (4, 4) ndarray
        The rig's hand-eye ``T_flange_cam``.
    camera : PinholeCamera
        The calibrated camera the stored images were undistorted with.
    injected : int
        Changes injected into the world (some may be out of view).
    """
    import cv2

    from fgcd_cli.app.rig import open_sim_rig

    png = visit.bytes(schema.change_relpath(schema.CHANGE_MASK_PNG))
    found = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED) > 0
    truth_ref = station.reference().json(schema.SIM_TRUTH)
    rig = open_sim_rig(scenario, T_flange_cam=X, intrinsics=camera)
    try:
        ids = change_ids_in_reference(rig.sim, np.array(truth_ref["T_world_cam"]), camera)
    finally:
        rig.close()
    # pixel scores and false regions from the shared scorer; changes counted by identity
    return {**score_change_detection(found, ids > 0), **count_changes_found(found, ids, injected=injected)}
