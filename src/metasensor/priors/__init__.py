"""Image priors for plug-and-play reconstruction: a learned denoiser and its training scenes."""

from metasensor.priors.deadleaves import dead_leaves
from metasensor.priors.denoiser import CNNDenoiser, DnCNN, load_denoiser

__all__ = ["dead_leaves", "DnCNN", "CNNDenoiser", "load_denoiser"]
