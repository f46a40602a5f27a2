"""Brains: modules that turn task input or body state into rest-length or force commands."""

from bptsb_ros.brains.feedback import FeedbackLayer, fit_ridge
from bptsb_ros.brains.fnn import LinearInputLayer, MLPBrain
from bptsb_ros.brains.swg import SineWaveGenerator

__all__ = ["FeedbackLayer", "LinearInputLayer", "MLPBrain", "SineWaveGenerator", "fit_ridge"]
