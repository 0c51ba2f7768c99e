"""The decision network in PyTorch (training only); `export` writes the numpy inference's weights.

Layers match `lishield_guard.detector.learned` exactly: per instance (one axis at one pyramid
level, `lishield_guard.detector.tfinput`), four 'same' 1-D convolutions along log frequency
(kernel `KERNEL`, dilations `DILATIONS`, ReLU), [max, mean] over frequency, a hidden dense
layer with ReLU and one logit; an image's logit is the maximum over its instances
(multiple-instance learning: one level of one axis that shows the barcode is enough).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from torch import nn

from lishield_guard.detector.tfinput import CHANNELS, INPUT_VERSION

KERNEL = 5
DILATIONS = (1, 2, 4, 8)
WIDTHS = (32, 32, 48, 48)
HIDDEN = 32


class DecisionNet(nn.Module):
    """Instance scorer; ``forward`` takes (batch, instances, channels, frequencies) and a
    (batch, instances) mask of present instances -> (batch, instances) logits (absent ones
    -inf)."""

    def __init__(self) -> None:
        super().__init__()
        layers = []
        c_in = len(CHANNELS)
        for width, d in zip(WIDTHS, DILATIONS, strict=True):
            layers += [nn.Conv1d(c_in, width, KERNEL, dilation=d,
                                 padding=d * (KERNEL - 1) // 2), nn.ReLU()]
            c_in = width
        self.convs = nn.Sequential(*layers)
        self.hidden = nn.Linear(2 * c_in, HIDDEN)
        self.out = nn.Linear(HIDDEN, 1)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Logit of every instance."""
        b, n, c, f = x.shape
        h = self.convs(x.reshape(b * n, c, f))
        h = torch.cat([h.amax(dim=2), h.mean(dim=2)], dim=1)
        h = torch.relu(self.hidden(h))
        z = self.out(h).reshape(b, n)
        return z.masked_fill(~mask, float("-inf"))


def export(net: DecisionNet, weights: str | Path, card: dict) -> None:
    """Write ``weights`` (.npz in the numpy layout) and its card (.json beside it)."""
    arrays = {}
    convs = [m for m in net.convs if isinstance(m, nn.Conv1d)]
    for i, m in enumerate(convs):
        w = m.weight.detach().cpu().numpy()  # (c_out, c_in, k)
        arrays[f"conv{i}_w"] = np.ascontiguousarray(
            w.transpose(2, 1, 0).reshape(-1, w.shape[0])).astype(np.float32)
        arrays[f"conv{i}_b"] = m.bias.detach().cpu().numpy().astype(np.float32)
    for i, m in enumerate((net.hidden, net.out)):
        arrays[f"dense{i}_w"] = m.weight.detach().cpu().numpy().T.astype(np.float32).copy()
        arrays[f"dense{i}_b"] = m.bias.detach().cpu().numpy().astype(np.float32)
    from lishield_guard.data_files import file_digest

    weights = Path(weights)
    weights.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(weights, **arrays)
    meta = {"input_version": INPUT_VERSION, "kernel": KERNEL, "dilations": list(DILATIONS),
            "widths": list(WIDTHS), "n_dense": 2, **card,
            "weights_digest": file_digest(weights)}
    weights.with_suffix(".json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
