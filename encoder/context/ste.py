"""Straight-through roundings for training (informative, encoder side): the rounding in the
forward pass, the identity in the backward pass. Two tie rules on purpose, each that of the
operation the trained value will go through:

* ``ste_round_half_up``: floor(x + 1/2), ties toward +inf, the rounding shift of the integer
  networks (common/intnn.py ``rshift_round``): the GG-Conv float twin (encoder/context/ggconv_train.py)
  rounds as the normative integer inference will;
* ``ste_round_half_even``: ties to even, as np.rint in the encoder's attribute quantization
  (encoder/stream/encode.py ``quantize``): the rate model (encoder/anchors/rate_model.py) sees the values
  the encoder will code.
"""

from __future__ import annotations

import torch


def ste_round_half_up(x: torch.Tensor) -> torch.Tensor:
    """floor(x + 1/2) forward, identity backward."""
    return x + (torch.floor(x + 0.5) - x).detach()


def ste_round_half_even(x: torch.Tensor) -> torch.Tensor:
    """round(x), ties to even, forward; identity backward."""
    return x + (torch.round(x) - x).detach()
