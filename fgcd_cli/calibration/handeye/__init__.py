"""Hand-eye ``T_flange_cam`` and the monocular map scale: target-free (rACR §3.2, linear then refined on the images) and with a target (``AX = XB``)."""
