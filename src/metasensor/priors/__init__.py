"""Image priors for plug-and-play reconstruction: a learned denoiser and its training scenes;
:mod:`metasensor.priors.pnp` plugs the denoiser into the HQS solvers (``pnp_options()``), and
:mod:`metasensor.priors.external` any NumPy denoiser, BM3D among them through the optional
``bm3d`` package (``bm3d_options()``)."""

from metasensor.priors.deadleaves import dead_leaves
from metasensor.priors.denoiser import CNNDenoiser, DnCNN, load_denoiser
from metasensor.priors.external import FunctionPrior, bm3d_options

__all__ = ["dead_leaves", "DnCNN", "CNNDenoiser", "load_denoiser", "FunctionPrior",
           "bm3d_options"]
