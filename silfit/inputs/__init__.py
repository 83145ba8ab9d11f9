"""Input builders: plain values -> one :class:`Job` (what :func:`silfit.run.run` fits). One builder per kind of
input: one image or photo (:func:`image_job`), one camera's video (:func:`video_job`), a calibrated rig's frame
(:func:`rig_job`) or video (:func:`rig_video_job`), a dataset item (:func:`item_job`). The command line
(:mod:`silfit.cli.jobs`: it reads the files its flags name), the dataset runner (:mod:`silfit.runner.worker`) and
the evaluator (:mod:`silfit.eval`) all end by calling them; the checks every job gets before it is fitted are
:func:`silfit.run.check`'s."""

from .dataset import item_job
from .image import image_job
from .job import Job
from .rig import rig_job, rig_video_job
from .video import video_job

__all__ = ["Job", "image_job", "item_job", "rig_job", "rig_video_job", "video_job"]
