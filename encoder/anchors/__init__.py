"""The anchor route (Scaffold-GS; informative): anchor pruning (NAAP), merging duplicate anchors,
the rate estimate of anchor attributes, and transcoding a 3DGS scene to anchors."""
