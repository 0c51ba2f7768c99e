"""Generate the training set, train the decision network, export the shipped weights.

    python -m training.train --n 300000 --seed 40 --jobs 2            # what `make train` runs
    python -m training.train --n 4000 --epochs 1 --out /tmp/t          # a quick smoke run

Examples ``0..n-1`` of seed ``--seed`` are rendered in the profile domain
(`training.data.example_profiles`, `synth.fastrender`) and reduced to the network's input
(`lishield_guard.detector.tfinput`): the instances of the stripes' axis, stored as uint8 in
``--cache`` (one .npz per `SHARD` examples, so an interrupted run resumes and a longer run
reuses a shorter one's shards). The last ``--val`` examples are held out for the learning
curves. The network (`training.model`) is trained with AdamW on binary cross-entropy of the
image logit (maximum over instances), and the held-out loss is logged against the number of
examples seen (``curves``) and, with ``--sizes``, for separate runs on the first 50k, 200k...
examples (``size_curve``): the evidence that more data would not help. Positives whose LED row
contrast is below `MIN_TRAIN_CONTRAST`, and examples the detector would call undetermined
(fewer than two usable blocks), are left out of the loss. Outputs: ``decision_model.npz`` and
``decision_model.json`` (the card) in ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor, TimeoutError
from pathlib import Path

import numpy as np

from lishield_guard.detector.tfinput import (
    CHANNELS,
    LOG_CLIP,
    MAX_LEVELS,
    N_FREQ,
    POWER_CHANNELS,
    TURN_CHANNELS,
    TURN_CLIP,
)

SHARD = 2000
MIN_TRAIN_CONTRAST = 0.0015  # LED row contrast (std / mean) below which a positive is dropped
N_STORED = len(POWER_CHANNELS) + len(TURN_CHANNELS)  # the rest follow from level and frames


def _quantise(x: np.ndarray) -> np.ndarray:
    """Instances (n, len(CHANNELS), N_FREQ) float32 -> (n, N_STORED, N_FREQ) uint8."""
    p = len(POWER_CHANNELS)
    q = np.empty((len(x), N_STORED, N_FREQ), np.uint8)
    q[:, :p] = np.round((x[:, :p] - LOG_CLIP[0]) * (255 / (LOG_CLIP[1] - LOG_CLIP[0])))
    q[:, p:] = np.round((x[:, p:N_STORED] - TURN_CLIP[0]) * (255 / (TURN_CLIP[1] - TURN_CLIP[0])))
    return q


def dequantise(q: np.ndarray, meta: np.ndarray) -> np.ndarray:
    """(..., N_STORED, N_FREQ) uint8 and (..., 2) [level, frames channel] -> float32 inputs
    of shape (..., len(CHANNELS), N_FREQ), as `tfinput.level_instances` computes them."""
    p = len(POWER_CHANNELS)
    out = np.empty(q.shape[:-2] + (len(CHANNELS), N_FREQ), np.float32)
    out[..., :p, :] = q[..., :p, :] * ((LOG_CLIP[1] - LOG_CLIP[0]) / 255) + LOG_CLIP[0]
    out[..., p:N_STORED, :] = q[..., p:, :] * ((TURN_CLIP[1] - TURN_CLIP[0]) / 255) \
        + TURN_CLIP[0]
    out[..., -3, :] = np.linspace(-1.0, 1.0, N_FREQ, dtype=np.float32)
    out[..., -2, :] = meta[..., 0:1]
    out[..., -1, :] = meta[..., 1:2]
    return out


def example_arrays(index: int, seed: int, bank: str, fast: bool = True,
                   texture: str | None = None) -> tuple:
    """One example as stored: (x uint8 (MAX_LEVELS, N_STORED, N_FREQ), meta (MAX_LEVELS, 2),
    mask (MAX_LEVELS,), record); ``texture``: of that supplement (`data.sample_example`)."""
    from lishield_guard.detector.spectra import USABLE_TILES
    from lishield_guard.detector.tfinput import profiles_input
    from lishield_guard.detector.usable import MIN_USABLE_BLOCKS, usable_blocks
    from training.data import example_profiles

    profiles, rec = example_profiles(index, seed, bank, fast=fast, texture=texture)
    (axis, prof), = ((a, p) for a, p in profiles.items() if a == (0 if not rec["rotate"] else 1))
    keep, _ = usable_blocks(prof.mean(axis=0), full_scale=255.0, tiles=USABLE_TILES)
    rec["usable"] = bool(keep.sum() >= MIN_USABLE_BLOCKS)
    inp = profiles_input({axis: prof}, full_scale=255.0, keep={axis: keep})
    x = np.zeros((MAX_LEVELS, N_STORED, N_FREQ), np.uint8)
    meta = np.zeros((MAX_LEVELS, 2), np.float32)
    mask = np.zeros(MAX_LEVELS, bool)
    n = len(inp.x)
    if n:
        x[:n] = _quantise(inp.x)
        meta[:n] = inp.x[:, -2:, 0]
        mask[:n] = True
    rec["n_instances"] = n
    return x, meta, mask, rec


def _init_worker() -> None:
    from lishield_guard.threads import one_thread_per_worker

    one_thread_per_worker()


def _chunk(args: tuple) -> tuple:
    start, stop, seed, bank, texture = args
    got = [example_arrays(i, seed, bank, texture=texture) for i in range(start, stop)]
    return (np.stack([g[0] for g in got]), np.stack([g[1] for g in got]),
            np.stack([g[2] for g in got]), [g[3] for g in got])


def _shard_path(cache: Path, seed: int, start: int, texture: str | None = None) -> Path:
    return cache / (f"s{seed}_{start:08d}.npz" if texture is None else
                    f"s{seed}_{texture}_{start:08d}.npz")


def generate(n: int, seed: int, *, jobs: int, cache: Path, bank: str,
             budget_s: float = float("inf"), texture: str | None = None) -> tuple:
    """Examples 0..n-1 of ``seed`` as (x, meta, mask, records), shards cached in ``cache``
    (``texture``: of that supplement, `data.sample_example`).

    With ``budget_s`` generation stops after that many seconds and the complete prefix done
    by then is returned (its length goes into the card, so ``--n k`` reproduces it)."""
    cache.mkdir(parents=True, exist_ok=True)
    starts = list(range(0, n, SHARD))
    todo = [s for s in starts if not _shard_path(cache, seed, s, texture).exists()]
    t0 = time.time()
    if todo:
        step = 50
        with ProcessPoolExecutor(max_workers=jobs, initializer=_init_worker) as pool:
            for s in todo:
                stop = min(s + SHARD, n)
                if stop - s < SHARD and stop != n:
                    continue
                futures = [pool.submit(_chunk, (a, min(a + step, stop), seed, bank, texture))
                           for a in range(s, stop, step)]
                try:
                    parts = [f.result(timeout=max(budget_s - (time.time() - t0), 0.01)
                                      if math.isfinite(budget_s) else None) for f in futures]
                except TimeoutError:
                    print(f"  generation budget of {budget_s:g} s spent", file=sys.stderr)
                    pool.shutdown(wait=False, cancel_futures=True)
                    break
                arrays = [np.concatenate([p[k] for p in parts]) for k in range(3)]
                recs = [r for p in parts for r in p[3]]
                tmp = _shard_path(cache, seed, s, texture).with_suffix(".tmp.npz")
                np.savez(tmp, x=arrays[0], meta=arrays[1], mask=arrays[2],
                         records=json.dumps(recs))
                tmp.replace(_shard_path(cache, seed, s, texture))
                done = s + len(recs)
                rate = (done - todo[0]) / max(time.time() - t0, 1e-9)
                print(f"  {done}/{n} examples, {rate:.1f}/s, {time.time() - t0:.0f} s",
                      file=sys.stderr, flush=True)
    xs, metas, masks, recs = [], [], [], []
    for s in starts:
        path = _shard_path(cache, seed, s, texture)
        if not path.exists():
            break
        with np.load(path) as z:
            k = min(len(z["x"]), n - s)
            xs.append(z["x"][:k])
            metas.append(z["meta"][:k])
            masks.append(z["mask"][:k])
            recs += json.loads(str(z["records"]))[:k]
    if not xs:
        return (np.zeros((0, MAX_LEVELS, N_STORED, N_FREQ), np.uint8),
                np.zeros((0, MAX_LEVELS, 2), np.float32), np.zeros((0, MAX_LEVELS), bool), [])
    return np.concatenate(xs), np.concatenate(metas), np.concatenate(masks), recs


def auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """Area under the ROC curve (rank statistic; NaN without both classes)."""
    from scipy.stats import rankdata

    pos = labels == 1
    n_pos, n_neg = int(pos.sum()), int((~pos).sum())
    if not n_pos or not n_neg:
        return float("nan")
    r = rankdata(scores)
    return float((r[pos].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def image_logits(net, x, meta, mask, idx: np.ndarray, batch: int = 512) -> np.ndarray:
    """Image logits (max over instances) of examples ``idx`` (torch, no gradient)."""
    import torch

    out = []
    net.eval()
    dev = next(net.parameters()).device
    with torch.no_grad():
        for s in range(0, len(idx), batch):
            b = idx[s:s + batch]
            xb = torch.from_numpy(dequantise(x[b], meta[b])).to(dev)
            out.append(net(xb, torch.from_numpy(mask[b]).to(dev)).amax(dim=1).cpu().numpy())
    net.train()
    return np.concatenate(out) if out else np.zeros(0, np.float32)


def _val_stats(z: np.ndarray, y: np.ndarray) -> dict:
    zz = np.clip(z, -60, 60)
    loss = float(np.mean(np.logaddexp(0, zz) - y * zz)) if len(z) else float("nan")
    return {"val_loss": round(loss, 5), "val_auc": round(auc(z, y), 5)}


def fit(data: tuple, train_idx: np.ndarray, val_idx: np.ndarray, *, epochs: float, seed: int,
        batch: int = 128, lr: float = 2e-3, log_every: int = 25_000,
        budget_s: float = float("inf"), device: str = "cpu", on_log=None) -> tuple:
    """Train `training.model.DecisionNet` on ``train_idx`` for ``epochs`` passes (fractions
    allowed) on ``device``; return (net on the CPU, curve) where the curve logs the held-out
    loss and AUC against the examples seen. ``on_log(net, curve)``, when given, runs at each
    logged point (a checkpoint, so that a killed run keeps its progress)."""
    import torch

    from training.model import DecisionNet

    x, meta, mask, y = data
    torch.manual_seed(seed)
    dev = torch.device(device)
    net = DecisionNet().to(dev)
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    steps = max(1, int(epochs * len(train_idx)) // batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps,
                                                pct_start=0.1)
    rng = np.random.default_rng(seed)
    order = np.concatenate([rng.permutation(train_idx) for _ in range(math.ceil(epochs))])
    yt = torch.from_numpy(y.astype(np.float32))
    curve, seen, t0, running = [], 0, time.time(), []
    for k in range(steps):
        b = order[k * batch:(k + 1) * batch]
        xb = torch.from_numpy(dequantise(x[b], meta[b])).to(dev)
        z = net(xb, torch.from_numpy(mask[b]).to(dev)).amax(dim=1)
        loss = torch.nn.functional.binary_cross_entropy_with_logits(z, yt[b].to(dev))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        running.append(float(loss.detach()))
        seen += len(b)
        last = k == steps - 1
        if seen // log_every != (seen - len(b)) // log_every or last:
            row = {"seen": seen, "train_loss": round(float(np.mean(running)), 5),
                   **_val_stats(image_logits(net, x, meta, mask, val_idx), y[val_idx]),
                   "seconds": round(time.time() - t0, 1)}
            running = []
            curve.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
            if on_log is not None:
                on_log(net, curve)
        if time.time() - t0 > budget_s:
            print(f"  training budget of {budget_s:g} s spent at {seen} examples",
                  file=sys.stderr)
            break
    return net.cpu(), curve


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _trainable(recs: list[dict]) -> np.ndarray:
    """Examples that enter the loss: usable, and not a positive too faint to learn from."""
    return np.array([r["usable"] and r["n_instances"] > 0
                     and not (r["label"] == 1 and r["led_contrast"] < MIN_TRAIN_CONTRAST)
                     for r in recs])


def main(argv: list[str] | None = None) -> int:
    """Command line; see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=300_000, help="examples (default 300000)")
    ap.add_argument("--seed", type=int, default=40, help="data seed (default 40)")
    ap.add_argument("--train-seed", type=int, default=0, help="weight init / batch order seed")
    ap.add_argument("--epochs", type=float, default=2.0)
    ap.add_argument("--val", type=int, default=10_000, help="held-out examples (the last ones)")
    ap.add_argument("--sizes", default="",
                    help="comma-separated training-set sizes for the size curve, e.g. "
                         "50000,150000 (each a separate run of the same length)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                    help="worker processes for the data, threads for training")
    ap.add_argument("--device", default="auto", help="cpu, cuda or auto (default: a GPU when "
                    "there is one); with a GPU and more cores, raise --jobs and --n")
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--bank", default="out/scenebank", help="scene bank (training/scenes.py)")
    ap.add_argument("--cache", default="out/train/data", help="generated examples (resumable)")
    ap.add_argument("--out", default="out/train/model", help="where the weights and card go")
    ap.add_argument("--gen-budget-s", type=float, default=float("inf"),
                    help="stop generating after this many seconds (keeps a complete prefix)")
    ap.add_argument("--fit-budget-s", type=float, default=float("inf"),
                    help="stop training after this many seconds")
    ap.add_argument("--supplement", default="facade",
                    help="texture of the hard look-alike supplement (data.sample_example: "
                    "every scene that texture, barcodes and look-alikes alike); '' for none")
    ap.add_argument("--supplement-n", type=int, default=16_000,
                    help="examples of the supplement (default 16000; its last tenth held out)")
    ap.add_argument("--supplement-seed", type=int, default=1040)
    ap.add_argument("--generate-only", action="store_true", help="generate, do not train")
    a = ap.parse_args(argv)
    t0 = time.time()
    x, meta, mask, recs = generate(a.n, a.seed, jobs=a.jobs, cache=Path(a.cache), bank=a.bank,
                                   budget_s=a.gen_budget_s)
    n = len(recs)
    sup = (np.zeros((0, MAX_LEVELS, N_STORED, N_FREQ), np.uint8),
           np.zeros((0, MAX_LEVELS, 2), np.float32), np.zeros((0, MAX_LEVELS), bool), [])
    if a.supplement and a.supplement_n:
        sup = generate(a.supplement_n, a.supplement_seed, jobs=a.jobs, cache=Path(a.cache),
                       bank=a.bank, texture=a.supplement)
    t_gen = time.time() - t0
    n_sup = len(sup[3])
    print(f"{n} examples ({sum(r['label'] for r in recs)} positives) and {n_sup} of the "
          f"{a.supplement or 'no'} supplement in {t_gen:.0f} s", file=sys.stderr, flush=True)
    if a.generate_only or n == 0:
        return 0
    import torch

    torch.set_num_threads(max(1, a.jobs))
    device = ("cuda" if torch.cuda.is_available() else "cpu") if a.device == "auto" \
        else a.device
    n_val = min(a.val, n // 5)
    sup_val = n_sup // 10
    # the main set's last n_val and the supplement's last tenth are held out
    x, meta, mask = (np.concatenate([m, s]) for m, s in zip((x, meta, mask), sup[:3],
                                                               strict=True))
    recs = recs + sup[3]
    y = np.array([r["label"] for r in recs], np.int64)
    ok = _trainable(recs)
    held = np.zeros(len(recs), bool)
    held[n - n_val:n] = True
    held[len(recs) - sup_val:] = True
    val_idx = np.flatnonzero(ok & held)
    train_all = np.flatnonzero(ok & ~held)
    data = (x, meta, mask, y)
    size_curve = []
    for size in [int(v) for v in a.sizes.split(",") if v.strip()]:
        sub = train_all[train_all < size]
        passes = a.epochs * len(train_all) / max(len(sub), 1)  # same number of steps
        _, c = fit(data, sub, val_idx, epochs=passes, seed=a.train_seed, batch=a.batch,
                   log_every=10**12, device=device)
        size_curve.append({"train_examples": int(len(sub)), **c[-1]})
        print(json.dumps(size_curve[-1]), file=sys.stderr, flush=True)
    from training.model import export

    def checkpoint(net, curve):
        export(net, Path(a.out) / "checkpoint.npz",
               {"partial": True, "curves": curve})

    t1 = time.time()
    net, curve = fit(data, train_all, val_idx, epochs=a.epochs, seed=a.train_seed,
                     batch=a.batch, budget_s=a.fit_budget_s, device=device, on_log=checkpoint)
    t_fit = time.time() - t1
    size_curve.append({"train_examples": int(len(train_all)), **curve[-1]})
    from training.data import MONO_PRESETS, RGB_PRESETS

    card = {"training_commit": _commit(), "data_seed": a.seed,
            "supplement": {"texture": a.supplement, "n": n_sup, "seed": a.supplement_seed},
            "specs": list(MONO_PRESETS + RGB_PRESETS), "train_seed": a.train_seed,
            "n_examples": n, "n_train": int(len(train_all)), "n_val": int(len(val_idx)),
            "epochs": a.epochs, "min_train_contrast": MIN_TRAIN_CONTRAST,
            "generate_s": round(t_gen, 1), "fit_s": round(t_fit, 1), "jobs": a.jobs,
            "device": device, "batch": a.batch,
            "curves": curve, "size_curve": size_curve}
    export(net, Path(a.out) / "decision_model.npz", card)
    print(f"wrote {a.out}/decision_model.npz (held-out AUC {curve[-1]['val_auc']:.4f})",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
