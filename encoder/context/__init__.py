"""Fitting the level-2 context models to a scene (informative): the parent MLP and GG-Conv's float
twin with quantization-aware training, for both routes' streams; their integer inference is
common/context/."""
