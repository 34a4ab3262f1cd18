"""Reconstruction: phase-space deconvolution (ISA), fast deconvolution, DAO, blocks."""
