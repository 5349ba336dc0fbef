"""lghcc: reference codec for LG-HCC compression of anchor-based 3D Gaussian Splatting scenes.

Layout (source tree -> installed package):
  common/   -> lghcc.common    normative: syntax, bitstream, geometry, entropy coding, context models
  encoder/  -> lghcc.encoder   informative: quantization choices, model fitting, lghcc-enc
  decoder/  -> lghcc.decoder   normative decoding process, lghcc-dec (never imports the encoder)
  render/   -> lghcc.render    informative: neural Gaussians, rasterizer, metrics
  conformance/ -> lghcc.conformance  conformance streams and their runner
"""

__version__ = "0.1.0"
