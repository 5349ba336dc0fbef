"""The explicit-Gaussian route (3DGS PLY, SPZ, SOG; informative): pruning, grid, steps and
quantization chosen against renders of the source, then the scene's stream."""
