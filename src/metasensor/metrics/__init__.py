"""Image-quality metrics: PSNR, SSIM, slanted-edge MTF (ISO 12233), field maps, evaluation,
spectral fidelity against the truth (resolved frequency), bar-group resolution and the fringe
ratio at block borders."""

from metasensor.metrics.bars import bar_resolution
from metasensor.metrics.evaluation import evaluate, write_evaluation
from metasensor.metrics.field import FieldMTF, field_mtf, find_edge_rois
from metasensor.metrics.fringes import fringe_ratio
from metasensor.metrics.mtf import EdgeMTF, measure_edge, mtf50, mtf_at, slanted_edge_mtf
from metasensor.metrics.quality import psnr, snr_db, ssim
from metasensor.metrics.spectral import regional_fidelity, resolved_frequency, spectral_fidelity

__all__ = ["slanted_edge_mtf", "measure_edge", "EdgeMTF", "mtf50", "mtf_at", "psnr", "ssim",
           "snr_db", "find_edge_rois", "field_mtf", "FieldMTF", "evaluate", "write_evaluation",
           "spectral_fidelity", "resolved_frequency", "regional_fidelity", "bar_resolution",
           "fringe_ratio"]
