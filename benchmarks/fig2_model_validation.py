"""Reproduce the trends of paper Fig. 2: PSNR and SSIM vs exposure, duty, intensity and frequency.

Setup (paper Sec. 3.2.2): a reference image P under a steady light of the same average
intensity with unlimited range, against the capture Q under an on-off-keyed LED (default
f = 100 Hz, I_p = 10 kLx, D_c = 0.5), with Q clipped at saturation (overexposure) and scaled to
P's mean before comparison. Row time t_s = 1/75000 s at 8 MP (3264 x 2448), simulated here at
1/8 of the size (408 x 306 rows) with t_s scaled by 8, so the stripes cover the same share of
the frame. No noise. The sensor saturates a reflectance-1 pixel under a steady 5 kLx at
t_e = 1/100 s, matching the paper's observation (iii) that 1/100 s is the overexposure limit
near I_p = 10 kLx.

Run: ``python benchmarks/fig2_model_validation.py [--out out/fig2.png]`` (about 20 s).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from lishield_guard.camera import CameraModel
from synth.camera import SensorModel, simulate_frame
from synth.light import PwmLight
from synth.scene import load_scene

N_ROWS, N_COLS = 306, 408  # 8 MP (2448 x 3264) divided by 8
ROW_TIME_S = 8 / 75_000  # paper: 1/75000 s per row at full size (Nexus 5)
REF_LUX = 5_000.0  # steady average that saturates reflectance 1 at t_e = SAT_EXPOSURE_S
SAT_EXPOSURE_S = 1 / 100
SENSOR = SensorModel()
PSNR_CAP_DB = 60.0  # stripe-free captures (t_e = N/f) would give infinite PSNR
DEFAULT = {"freq_hz": 100.0, "peak_lux": 10_000.0, "duty": 0.5}


def quality(scene: np.ndarray, *, exposure_s: float, freq_hz: float, peak_lux: float,
            duty: float) -> tuple[float, float]:
    """PSNR (dB) and SSIM of the LED capture Q against the steady reference P.

    Parameters
    ----------
    scene : ndarray of shape (N_ROWS, N_COLS, 1)
        Linear reflectance.
    exposure_s : float
        Exposure t_e in seconds.
    freq_hz : float
        On-off keying frequency in Hz.
    peak_lux : float
        Peak intensity I_p in lux.
    duty : float
        Duty cycle D_c, unitless.

    Returns
    -------
    (float, float)
        PSNR in dB (capped at PSNR_CAP_DB; identical images give the cap) and SSIM, unitless.
    """
    cam = CameraModel(row_time_s=ROW_TIME_S, n_rows=N_ROWS, exposure_s=exposure_s)
    mean_lux = peak_lux * duty
    # Manual exposure: gain fixed by the light level (simulate_frame normalises the light's
    # time average to 1, so absolute intensity enters through the gain).
    gain = (mean_lux / REF_LUX) * SENSOR.full_well_e / (SAT_EXPOSURE_S * SENSOR.light_e_per_s)
    kw = {"rng": np.random.default_rng(0), "start_s": 0.0, "gain": gain, "noise": False,
          "output": "linear", "sensor": SENSOR}
    led = PwmLight(freq_hz=freq_hz, duty=duty, depth=1.0)
    q = simulate_frame(led, scene, cam, **kw)[:, :, 0].astype(np.float64)
    steady = PwmLight(freq_hz=freq_hz, duty=1.0, depth=0.0)  # constant, same average
    p = simulate_frame(steady, scene, cam, **kw)[:, :, 0].astype(np.float64)
    q = np.clip(q, 0.0, 1.0)  # Q saturates; P has unlimited range (paper Sec. 3.2.2)
    q *= p.mean() / max(q.mean(), 1e-12)  # same average intensity
    rng_ = float(p.max() - p.min())
    psnr = float(min(peak_signal_noise_ratio(p, q, data_range=rng_), PSNR_CAP_DB))
    ssim = float(structural_similarity(p, q, data_range=rng_))
    return psnr, ssim


def main(argv: list[str] | None = None) -> int:
    """Run the three sweeps, print a table and write the plot."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/fig2.png"), help="output PNG")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    scene = load_scene("skimage:camera", N_ROWS, N_COLS)[:, :, :1]
    exposures_s = np.geomspace(1 / 8000, 1 / 10, 28)
    duties = (0.1, 0.3, 0.5, 0.7, 0.9)
    peaks_lux = (1_000.0, 5_000.0, 10_000.0, 20_000.0)
    freqs_hz = np.arange(100.0, 1001.0, 5.0)
    f_exposures_s = (1 / 500, 1 / 200, 1 / 100)

    def sweep(xs, **fixed):
        return np.array([quality(scene, **{**DEFAULT, **fixed, **x}) for x in xs])

    res_duty = {d: sweep([{"exposure_s": e} for e in exposures_s], duty=d) for d in duties}
    res_peak = {i: sweep([{"exposure_s": e} for e in exposures_s], peak_lux=i)
                for i in peaks_lux}
    res_freq = {e: sweep([{"freq_hz": f} for f in freqs_hz], exposure_s=e)
                for e in f_exposures_s}

    # ---- table
    print("Fig. 2 model validation (PSNR dB / SSIM); defaults f=100 Hz, I_p=10 kLx, D_c=0.5")
    print("\n(a,b) exposure vs duty cycle")
    print("t_e [s]     " + "".join(f"  D={d:<11}" for d in duties))
    for k, e in enumerate(exposures_s):
        print(f"1/{1 / e:<8.0f}" + "".join(f"  {res_duty[d][k, 0]:5.1f}/{res_duty[d][k, 1]:.3f}"
                                         for d in duties))
    print("\n(c,d) exposure vs peak intensity")
    print("t_e [s]     " + "".join(f"  I={i / 1e3:<4g}kLx    " for i in peaks_lux))
    for k, e in enumerate(exposures_s):
        print(f"1/{1 / e:<8.0f}" + "".join(f"  {res_peak[i][k, 0]:5.1f}/{res_peak[i][k, 1]:.3f}"
                                         for i in peaks_lux))
    print("\n(e,f) frequency vs exposure (every 50 Hz shown)")
    print("f [Hz]  " + "".join(f"  t_e=1/{1 / e:<6.0f}  " for e in f_exposures_s))
    for k, f in enumerate(freqs_hz):
        if f % 50 == 0:
            print(f"{f:<7.0f}" + "".join(f"  {res_freq[e][k, 0]:5.1f}/{res_freq[e][k, 1]:.3f}  "
                                        for e in f_exposures_s))

    # ---- plot
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(3, 2, figsize=(11, 12))
    for d in duties:
        ax[0, 0].semilogx(exposures_s, res_duty[d][:, 0], label=f"D_c={d}")
        ax[0, 1].semilogx(exposures_s, res_duty[d][:, 1], label=f"D_c={d}")
    for i in peaks_lux:
        ax[1, 0].semilogx(exposures_s, res_peak[i][:, 0], label=f"I_p={i / 1e3:g} kLx")
        ax[1, 1].semilogx(exposures_s, res_peak[i][:, 1], label=f"I_p={i / 1e3:g} kLx")
    for e in f_exposures_s:
        ax[2, 0].plot(freqs_hz, res_freq[e][:, 0], label=f"t_e=1/{1 / e:.0f} s")
        ax[2, 1].plot(freqs_hz, res_freq[e][:, 1], label=f"t_e=1/{1 / e:.0f} s")
    titles = ["(a) PSNR vs exposure, duty cycle", "(b) SSIM vs exposure, duty cycle",
              "(c) PSNR vs exposure, peak intensity", "(d) SSIM vs exposure, peak intensity",
              "(e) PSNR vs frequency", "(f) SSIM vs frequency"]
    for a, title in zip(ax.flat, titles, strict=True):
        a.set_title(title)
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    for a in ax[:2].flat:
        a.set_xlabel("exposure time (s)")
    for a in ax[2]:
        a.set_xlabel("OOK frequency (Hz)")
    for a in ax[:, 0]:
        a.set_ylabel("PSNR (dB)")
    for a in ax[:, 1]:
        a.set_ylabel("SSIM")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=90)
    print(f"\nwrote {args.out} in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
