"""The motion library: clips in the shared pose representation (:mod:`~pghm.motion.motion`),
BVH import and retargeting, procedural clips, and opening any of them by name or path
(:mod:`~pghm.motion.open_motion`)."""
