"""The runner-up model family: gradient-boosted trees over pooled spectra (for comparison only).

Each image becomes, per spectral channel, the maximum over its windows of every pair of
adjacent log-frequency bins (the trees cannot slide along frequency as the network does, so
they get every position). Trained on the same examples and held-out part as the network;
`compare` reports both on that part: ROC AUC and the detection rate at a 1 % false-alarm rate.
"""

from __future__ import annotations

import numpy as np


def pooled(x: np.ndarray) -> np.ndarray:
    """(n, windows, channels, freq) -> (n, (channels - 1) * freq / 2) tree features."""
    m = x[:, :, :-1].max(axis=1).astype(np.float32)  # drop the position channel
    return m.reshape(len(m), m.shape[1], -1, 2).max(axis=3).reshape(len(m), -1)


def tpr_at_fpr(scores: np.ndarray, labels: np.ndarray, fpr: float = 0.01) -> float:
    """Detection rate at the threshold that passes ``fpr`` of the negatives."""
    neg = np.sort(scores[labels == 0])
    if not len(neg):
        return float("nan")
    thr = neg[min(len(neg) - 1, int(np.ceil((1 - fpr) * len(neg))))]
    return float(np.mean(scores[labels == 1] > thr))


def compare(x: np.ndarray, y: np.ndarray, w: np.ndarray, val: np.ndarray,
            net_val_logits: np.ndarray, *, seed: int) -> dict:
    """Fit the trees; the two families' held-out figures."""
    from sklearn.ensemble import HistGradientBoostingClassifier

    from training.train import _auc

    f = pooled(x)
    tr = ~val & (w > 0)
    clf = HistGradientBoostingClassifier(max_iter=300, learning_rate=0.1, random_state=seed)
    clf.fit(f[tr], y[tr])
    s = clf.decision_function(f[val])
    yv = y[val]
    return {"cnn": {"val_auc": _auc(net_val_logits, yv),
                    "tpr_at_fpr_1pct": tpr_at_fpr(net_val_logits, yv)},
            "gbdt": {"val_auc": _auc(s, yv), "tpr_at_fpr_1pct": tpr_at_fpr(s, yv),
                     "n_features": int(f.shape[1])}}
