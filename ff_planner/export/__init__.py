"""Plans out of the planner: the ``ff-motion/1`` motion file (``motion_file``) and, with
matplotlib, the paper-style figures (``ff_planner.export.plotting``, imported on its own)."""
from ff_planner.export.motion_file import (
                                           FORMAT,
                                           Motion,
                                           MotionCheck,
                                           MotionFileError,
                                           motion_to_dict,
                                           read_motion,
                                           validate_motion_dict,
                                           verify_motion,
                                           write_motion,
)

__all__ = [
    "FORMAT", "Motion", "MotionCheck", "MotionFileError", "motion_to_dict", "read_motion",
    "validate_motion_dict", "verify_motion", "write_motion",
]
