"""Generate the training set, train the decision network, export the shipped weights.

    python -m training.train --n 20000 --seed 32 --jobs 2          # what `make train` runs
    python -m training.train --n 2000 --epochs 2 --out /tmp/t      # a quick smoke run

Examples ``0..n-1`` of seed ``--seed`` are generated (`training.data.example`; cached in
``--cache`` as one compressed .npz per 1000 examples, so an interrupted run resumes), the last
``--val-frac`` of them are held out for the learning curves, and the network (`training.model`)
is trained with AdamW on binary cross-entropy of the image logit (maximum over windows).
Positives whose LED row contrast is below `MIN_TRAIN_CONTRAST` carry no learnable signal and
are left out of the loss (they stay in every evaluation). Outputs: ``decision_model.npz`` and
``decision_model.json`` (the card: seed, commit, sizes, curves) in ``--out``.
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

SHARD = 1000
MIN_TRAIN_CONTRAST = 0.0015  # LED row contrast (std / mean) below which a positive is dropped


def _init_worker() -> None:
    from lishield_guard.threads import one_thread_per_worker

    one_thread_per_worker()


def _shard(args: tuple) -> tuple[np.ndarray, list[dict]]:
    start, stop, seed, bank = args
    from training.data import example

    xs, recs = [], []
    for i in range(start, stop):
        x, rec = example(i, seed, bank)
        xs.append(x)
        recs.append(rec)
    return np.stack(xs), recs


def generate(n: int, seed: int, *, jobs: int, cache: Path, bank: str,
             budget_s: float = float("inf")) -> tuple[np.ndarray, list[dict]]:
    """Examples 0..n-1 of ``seed`` as (x float16 (n, windows, channels, freq), records).

    Complete shards of `SHARD` examples are cached in ``cache`` (an interrupted run resumes).
    With ``budget_s``, generation stops once that many seconds have passed and the examples
    0..k-1 done by then are returned (k goes into the card, so ``--n k`` reproduces them)."""
    cache.mkdir(parents=True, exist_ok=True)
    got: dict[int, tuple] = {}  # first index of a chunk -> (x, records)
    for s in range(0, n - SHARD + 1, SHARD):
        path = cache / f"s{seed}_{s:07d}.npz"
        if path.exists():
            with np.load(path, allow_pickle=False) as z:
                got[s] = (z["x"], json.loads(str(z["records"])))
    chunk = 50
    pieces = [(a, min(a + chunk, n), seed, bank) for a in range(0, n, chunk)
              if not any(s <= a < s + SHARD for s in got)]
    t0 = time.time()
    if pieces:
        with ProcessPoolExecutor(max_workers=jobs, initializer=_init_worker) as pool:
            futures = [pool.submit(_shard, piece) for piece in pieces]
            for k, fut in enumerate(futures):
                left = budget_s - (time.time() - t0)
                try:
                    got[pieces[k][0]] = fut.result(
                        timeout=None if math.isinf(left) else max(left, 0.01))
                except TimeoutError:
                    print(f"  generation budget of {budget_s:g} s spent", file=sys.stderr)
                    pool.shutdown(wait=False, cancel_futures=True)
                    break
                if (k + 1) % max(1, len(pieces) // 20) == 0:
                    print(f"  generated {len(got)} chunks in {time.time() - t0:.0f} s",
                          file=sys.stderr, flush=True)
    xs, recs, a = [], [], 0
    while a in got:  # the complete prefix
        xs.append(got[a][0])
        recs += got[a][1]
        a += len(got[a][1])
    x = np.concatenate(xs) if xs else np.zeros((0,), np.float16)
    for s in range(0, len(recs) - SHARD + 1, SHARD):
        path = cache / f"s{seed}_{s:07d}.npz"
        if not path.exists():
            np.savez_compressed(path, x=x[s:s + SHARD], records=json.dumps(recs[s:s + SHARD]))
    return x, recs


def _auc(scores: np.ndarray, labels: np.ndarray) -> float:
    from scipy.stats import rankdata

    pos = labels == 1
    n_pos, n_neg = int(pos.sum()), int((~pos).sum())
    if not n_pos or not n_neg:
        return float("nan")
    r = rankdata(scores)
    return float((r[pos].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def fit(x: np.ndarray, y: np.ndarray, w: np.ndarray, val: np.ndarray, *, epochs: int,
        seed: int, device: str, batch: int = 64, lr: float = 2e-3,
        budget_s: float = float("inf")) -> tuple:
    """Train `training.model.DecisionNet`; return (net, curves). With ``budget_s``, no epoch
    starts after that many seconds (the curves say how many ran)."""
    import torch

    from training.model import DecisionNet

    torch.manual_seed(seed)
    torch.backends.cudnn.benchmark = True
    dev = torch.device(device)
    net = DecisionNet().to(dev)
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    train_idx = np.flatnonzero(~val & (w > 0))
    val_idx = np.flatnonzero(val)
    steps = epochs * (len(train_idx) // batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=max(steps, 1))
    xt = torch.from_numpy(x)  # float16; batches are used as float32
    if dev.type == "cuda":
        xt = xt.to(dev)  # a few GB: the whole set fits on the accelerator
    yt = torch.from_numpy(y.astype(np.float32))
    rng = np.random.default_rng(seed)
    curves = []

    def logits(idx: np.ndarray) -> np.ndarray:
        net.eval()
        out = []
        with torch.no_grad():
            for s in range(0, len(idx), 256):
                xb = xt[idx[s:s + 256]].to(dev).float()
                out.append(net(xb).amax(dim=1).cpu().numpy())
        net.train()
        return np.concatenate(out) if out else np.zeros(0)

    t_start = time.time()
    for epoch in range(epochs):
        if time.time() - t_start > budget_s:
            print(f"  training budget of {budget_s:g} s spent after {epoch} epochs",
                  file=sys.stderr)
            break
        t0 = time.time()
        perm = rng.permutation(train_idx)
        total = 0.0
        for s in range(0, len(perm) - batch + 1, batch):
            idx = perm[s:s + batch]
            xb = xt[idx].to(dev).float()
            z = net(xb).amax(dim=1)
            loss = torch.nn.functional.binary_cross_entropy_with_logits(z, yt[idx].to(dev))
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach()) * len(idx)
        zv = logits(val_idx)
        yv = y[val_idx]
        vloss = float(np.mean(np.logaddexp(0, zv) - yv * zv)) if len(zv) else float("nan")
        curves.append({"epoch": epoch + 1, "train_loss": total / max(len(perm), 1),
                       "val_loss": vloss, "val_auc": _auc(zv, yv), "seconds": time.time() - t0})
        print(json.dumps(curves[-1]), file=sys.stderr, flush=True)
    return net.cpu(), curves


def _val_logits(net, x: np.ndarray, val: np.ndarray) -> np.ndarray:
    """Image logits of the held-out part (on the CPU, float32)."""
    import torch

    idx = np.flatnonzero(val)
    with torch.no_grad():
        return np.concatenate([net(torch.from_numpy(x[idx[s:s + 128]]).float())
                               .amax(dim=1).numpy() for s in range(0, len(idx), 128)])


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    """Command line; see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20000, help="examples to generate (default 20000)")
    ap.add_argument("--seed", type=int, default=32, help="data seed (default 32)")
    ap.add_argument("--train-seed", type=int, default=0, help="weight init / batch order seed")
    ap.add_argument("--epochs", type=int, default=14)
    ap.add_argument("--val-frac", type=float, default=0.1)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    ap.add_argument("--bank", default="out/scenebank", help="scene bank (training/scenes.py)")
    ap.add_argument("--cache", default="out/train/data", help="generated examples (resumable)")
    ap.add_argument("--out", default="out/train/model", help="where the weights and card go")
    ap.add_argument("--gen-budget-s", type=float, default=float("inf"),
                    help="stop generating after this many seconds (keeps a complete prefix)")
    ap.add_argument("--fit-budget-s", type=float, default=float("inf"),
                    help="start no epoch after this many seconds of training")
    ap.add_argument("--runner-up", action="store_true",
                    help="also fit the runner-up family (gradient-boosted trees) and compare")
    a = ap.parse_args(argv)
    import torch

    device = ("cuda" if torch.cuda.is_available() else "cpu") if a.device == "auto" else a.device
    torch.set_num_threads(max(1, a.jobs))
    t0 = time.time()
    x, recs = generate(a.n, a.seed, jobs=a.jobs, cache=Path(a.cache), bank=a.bank,
                       budget_s=a.gen_budget_s)
    t_gen = time.time() - t0
    y = np.array([r["label"] for r in recs], np.int64)
    contrast = np.array([r["led_contrast"] for r in recs])
    w = np.where((y == 1) & (contrast < MIN_TRAIN_CONTRAST), 0.0, 1.0)
    val = np.arange(len(y)) >= int(round(len(y) * (1 - a.val_frac)))
    print(f"{len(y)} examples ({int(y.sum())} positives) in {t_gen:.0f} s; training on "
          f"{device}", file=sys.stderr, flush=True)
    t1 = time.time()
    net, curves = fit(x, y, w, val, epochs=a.epochs, seed=a.train_seed, device=device,
                      budget_s=a.fit_budget_s)
    t_fit = time.time() - t1
    from training.model import export

    families = None
    if a.runner_up:
        from training.runner_up import compare

        zv = _val_logits(net, x, val)
        families = compare(x, y, w, val, zv, seed=a.train_seed)
        print(json.dumps(families), file=sys.stderr, flush=True)
    from training.data import MONO_PRESETS, RGB_PRESETS

    card = {"training_commit": _commit(), "data_seed": a.seed,
            "specs": list(MONO_PRESETS + RGB_PRESETS), "train_seed": a.train_seed,
            "n_examples": len(y), "n_val": int(val.sum()), "epochs": len(curves),
            "min_train_contrast": MIN_TRAIN_CONTRAST, "device": device,
            "generate_s": round(t_gen, 1), "fit_s": round(t_fit, 1), "jobs": a.jobs,
            "curves": curves, "families": families}
    export(net, Path(a.out) / "decision_model.npz", card)
    print(f"wrote {a.out}/decision_model.npz (val AUC {curves[-1]['val_auc']:.4f})",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
