"""Motion and turbulence correction of realigned views (optical flow + scattered interpolation)."""

from metasensor.motion.correct import (
    MotionPlan,
    correct_motion,
    correct_motion_sequence,
    correct_motion_views,
    estimate_motion,
    plan_motion,
)
from metasensor.motion.fallback import FallbackMap, FallbackOptions

__all__ = ["correct_motion", "correct_motion_views", "correct_motion_sequence",
           "estimate_motion", "plan_motion", "MotionPlan", "FallbackOptions", "FallbackMap"]
