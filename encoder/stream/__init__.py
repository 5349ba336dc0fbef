"""Writing a stream (informative): the units both routes write from quantized values, level by level
and tile by tile, the same bytes in one process or many; the encoder's configuration and statistics."""
