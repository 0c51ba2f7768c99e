"""The learned decision stage: a small 1-D convolutional network scores every input instance.

Inference is a pure numpy function of `tfinput.TimeFreqInput.x` (no training framework at run
time). The weights ship as package data (``lishield_guard/data/decision_model.npz``) with a
card (``decision_model.json``: training commit, data seed, input version, widths, learning
curves, the weights' digest); loading refuses a card whose input version is not
`tfinput.INPUT_VERSION`.

Network (the same layers as ``training/model.py``, which trains it)::

    per instance (one axis at one pyramid level): (channels, frequency)
      -> 4 x [conv1d, kernel and dilations from the card, ReLU]
      -> [max over frequency, mean over frequency] -> dense + ReLU -> dense -> instance logit
    image logit = max over instances (multiple-instance: one level of one axis is enough)

Convolution along log frequency with a maximum over frequency makes the score invariant to
the unknown scale (row rate, resizing) up to the grid's ends, and the pyramid's levels share
the weights (a row rate twice as high is the next level). The receptive field (kernel 5,
dilations 1-8: 61 bins, 2.5 octaves) spans every tone ratio of the paper's barcodes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path

import numpy as np

from lishield_guard.data_files import file_digest
from lishield_guard.detector import tfinput
from lishield_guard.errors import ConfigError

__all__ = ["DecisionModel", "load_model", "score_windows", "shipped_model"]

#: The input the inference reads: version -> (channels, frequency bins).
INPUT_SHAPES = {tfinput.INPUT_VERSION: (len(tfinput.CHANNELS), tfinput.N_FREQ)}
MODEL_FILE = "decision_model.npz"
CARD_FILE = "decision_model.json"


@dataclass(frozen=True)
class DecisionModel:
    """Weights of the decision network and their card.

    Attributes
    ----------
    convs : tuple of (weight, bias, dilation)
        weight of shape (kernel * c_in, c_out) float32 (im2col layout), bias (c_out,).
    dense : tuple of (weight, bias)
        weight of shape (c_in, c_out) float32, bias (c_out,).
    card : dict
        Provenance and metrics (see ``decision_model.json``).
    digest : str or None
        ``sha256:<hex>`` of the weights file's bytes (`data_files.file_digest`), computed
        when loading; thresholds calibrated for these weights record it.
    """

    convs: tuple
    dense: tuple
    card: dict
    digest: str | None = None

    @property
    def kernel(self) -> int:
        """Convolution kernel size in frequency bins."""
        return int(self.card["kernel"])

    def knows(self, spec) -> bool:
        """Whether the network was trained on captures of ``spec``: a preset named in the
        card's ``specs``, with the preset's tones (a custom spec the network never saw is not
        something its score can vouch for)."""
        from lishield_guard.spec import PRESETS

        return spec.name in self.card.get("specs", ()) and PRESETS.get(spec.name) == spec


def _conv_same(x: np.ndarray, weight: np.ndarray, bias: np.ndarray, dilation: int,
               kernel: int) -> np.ndarray:
    """ReLU(conv1d) with zero 'same' padding; x of shape (n, n_freq, c_in) -> (n, n_freq, c_out)."""
    n, k_len, c_in = x.shape
    pad = dilation * (kernel - 1) // 2
    xp = np.zeros((n, k_len + 2 * pad, c_in), np.float32)
    xp[:, pad:pad + k_len] = x
    cols = np.concatenate([xp[:, j * dilation:j * dilation + k_len] for j in range(kernel)],
                          axis=2)  # (n, n_freq, kernel * c_in), tap-major like the weights
    out = cols.reshape(n * k_len, -1) @ weight
    out += bias
    np.maximum(out, 0.0, out=out)
    return out.reshape(n, k_len, -1)


def score_windows(x: np.ndarray, model: DecisionModel) -> np.ndarray:
    """Logit of every instance (higher: more like a barcode capture).

    Parameters
    ----------
    x : ndarray of shape (n_instances, len(tfinput.CHANNELS), tfinput.N_FREQ)
        `tfinput.TimeFreqInput.x`.
    model : DecisionModel
        Weights (`shipped_model` or `load_model`).

    Returns
    -------
    ndarray of shape (n_instances,), float32
        Unbounded logits, in the instances' order; the image's logit is their maximum.

    Raises
    ------
    ConfigError
        When x does not have the model's input shape.
    """
    shape = INPUT_SHAPES[model.card["input_version"]]
    if x.ndim != 3 or x.shape[1:] != shape:
        raise ConfigError(f"decision input must have shape (n, {shape[0]}, {shape[1]}), "
                          f"got {x.shape}")
    if len(x) == 0:
        return np.zeros(0, np.float32)
    h = np.ascontiguousarray(x.transpose(0, 2, 1), dtype=np.float32)
    for weight, bias, dilation in model.convs:
        h = _conv_same(h, weight, bias, dilation, model.kernel)
    h = np.concatenate([h.max(axis=1), h.mean(axis=1)], axis=1)
    *hidden, (w_out, b_out) = model.dense
    for weight, bias in hidden:
        h = np.maximum(h @ weight + bias, 0.0)
    return (h @ w_out + b_out)[:, 0].astype(np.float32)


def load_model(weights: str | Path, card: str | Path | None = None) -> DecisionModel:
    """Read a decision model (``.npz`` weights and its ``.json`` card beside them).

    Raises
    ------
    ConfigError
        When a file is missing or unreadable, the card's ``input_version`` is not the
        code's `tfinput.INPUT_VERSION` (weights trained on another representation), or the
        card's ``weights_digest`` (when it has one) is not the weights file's digest.
    """
    weights = Path(weights)
    card = Path(card) if card is not None else weights.with_suffix(".json")
    try:
        meta = json.loads(card.read_text())
        with np.load(weights) as z:
            arrays = {k: z[k] for k in z.files}
        digest = file_digest(weights)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"cannot read decision model {weights} / {card}: {exc}") from exc
    if meta.get("weights_digest") not in (None, digest):
        raise ConfigError(f"decision model {weights}: its card {card} describes weights "
                          f"{meta['weights_digest']}, the file is {digest}: the card and the "
                          f"weights do not belong together (retrain, or restore the pair)")
    return _from_arrays(arrays, meta, str(weights), digest)


def _from_arrays(arrays: dict, meta: dict, where: str, digest: str | None = None
                 ) -> DecisionModel:
    if meta.get("input_version") not in INPUT_SHAPES:
        raise ConfigError(f"decision model {where} was trained on input "
                          f"{meta.get('input_version')!r}; this code computes "
                          f"{' or '.join(map(repr, INPUT_SHAPES))}: retrain it (make train)")
    try:
        convs = tuple((arrays[f"conv{i}_w"].astype(np.float32),
                       arrays[f"conv{i}_b"].astype(np.float32), int(d))
                      for i, d in enumerate(meta["dilations"]))
        dense = tuple((arrays[f"dense{i}_w"].astype(np.float32),
                       arrays[f"dense{i}_b"].astype(np.float32))
                      for i in range(int(meta["n_dense"])))
    except KeyError as exc:
        raise ConfigError(f"decision model {where} lacks {exc}") from exc
    return DecisionModel(convs, dense, meta, digest)


@cache
def shipped_model() -> DecisionModel:
    """The decision model shipped in ``lishield_guard/data`` (loaded once per process)."""
    data = resources.files("lishield_guard.data")
    with resources.as_file(data / MODEL_FILE) as w, resources.as_file(data / CARD_FILE) as c:
        return load_model(w, c)
