"""Scale-aware point cloud alignment (rACR §3.4): fast (robust ICP + scale) and fine
(geometric + photometric) registration of the current cloud to the reference cloud.
"""

from fgcd_cli.alignment.fast import FastAlignConfig, fast_align, initial_scale
from fgcd_cli.alignment.fine import FineAlignConfig, fine_align
from fgcd_cli.alignment.initial import InitialGuess, camera_prior, global_registration, initial_guess
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.results import AlignmentHealth, AlignmentResult, FineAlignmentResult, ResidualStats

__all__ = [
    "ReferenceIndex",
    "FastAlignConfig",
    "fast_align",
    "initial_scale",
    "FineAlignConfig",
    "InitialGuess",
    "camera_prior",
    "global_registration",
    "initial_guess",
    "fine_align",
    "AlignmentHealth",
    "AlignmentResult",
    "FineAlignmentResult",
    "ResidualStats",
]
