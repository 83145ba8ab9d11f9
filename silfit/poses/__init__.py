"""Body poses independent of any consumer: the hand-authored library
(:mod:`silfit.poses.library`) and a sampler of plausible poses that do not come from it
(:mod:`silfit.poses.sampler`)."""
