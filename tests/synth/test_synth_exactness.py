"""The simulator against the paper's closed forms (Sec. 3.2, Eqs. 3-7) and Sec. 4.1, noise off."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import find_peaks

from firmware.sequence import compile_spec
from lishield_guard.camera import CameraModel, hz_to_cpr
from lishield_guard.spec import BarcodeSpec
from synth.camera import led_rows_rgb, render_linear, simulate_frame
from synth.light import MainsFlicker, PwmLight, SequenceLight, SteadyLight

ALPHA = 0.7  # aggregated path loss / reflectance alpha_{i,j} of the uniform test scene
I_P = 3.0  # peak intensity


def _closed_forms(freq_hz: float, duty: float, t_e: float, t_s: float) -> dict:
    """Paper Eqs. 3-7 for on-off keying at freq_hz with duty D_c."""
    t_l = 1.0 / freq_hz
    t_on, t_off = duty * t_l, (1 - duty) * t_l
    n = math.floor(t_e / t_l)
    t_rem = t_e - n * t_l
    q_b = I_P * (n * t_on + t_rem) if t_rem <= t_on else I_P * (n + 1) * t_on  # Eq. 3
    q_d = I_P * n * t_on if t_rem <= t_off else I_P * (n * t_on + t_rem - t_off)  # Eq. 5
    return {"Q_B": ALPHA * q_b, "Q_D": ALPHA * q_d,
            "W_B": abs(t_rem - t_on) / t_s, "W_D": abs(t_rem - t_off) / t_s,  # Eqs. 4, 6
            "P": ALPHA * I_P * duty * t_e}  # Eq. 7


def _ook_lights(freq_hz: float, duty: float):
    pwm = PwmLight(freq_hz=freq_hz, duty=duty, depth=1.0, mean=I_P * duty)
    spec = BarcodeSpec.mono("ook", [freq_hz], duty=duty)
    seq = SequenceLight(compile_spec(spec, clock_hz=10_000_000), scale=I_P)
    return pwm, seq


CASES = [  # (freq_hz, duty, t_e_s): short, medium and multi-period exposures
    (100.0, 0.5, 1 / 4000),
    (100.0, 0.5, 0.0137),
    (100.0, 0.3, 0.0041),
    (100.0, 0.7, 0.0262),
    (400.0, 0.5, 1 / 1000 + 3e-4),
    (250.0, 0.2, 0.0093),
]


@pytest.mark.parametrize("freq_hz,duty,t_e", CASES)
@pytest.mark.parametrize("which", ["pwm", "sequence"])
def test_ook_stripes_match_eqs_3_to_7(freq_hz, duty, t_e, which):
    t_s = 1 / 75_000  # paper Sec. 3.2.2 (Nexus 5)
    light = _ook_lights(freq_hz, duty)[0 if which == "pwm" else 1]
    n_periods = 40
    n_rows = int(round(n_periods / freq_hz / t_s))
    cam = CameraModel(row_time_s=t_s, n_rows=n_rows, exposure_s=t_e)
    scene = np.full((n_rows, 4, 3), ALPHA, dtype=np.float32)
    img = render_linear(light, scene, cam, start_s=1.234e-4, normalize=False)
    # Light accumulation Q(i, j) = alpha * integral over [t_i, t_i + t_e]  (Eq. 1), from the
    # float32 frame; the float64 row values are checked to 1e-12 below.
    q = img[:, 0, 0].astype(np.float64) * t_e
    cf = _closed_forms(freq_hz, duty, t_e, t_s)
    assert q.max() == pytest.approx(cf["Q_B"], rel=1e-6)
    assert q.min() == pytest.approx(cf["Q_D"], rel=1e-6, abs=1e-12)
    rows = led_rows_rgb(light, cam, start_s=1.234e-4, normalize=False)[:, 0] * t_e * ALPHA
    assert rows.max() == pytest.approx(cf["Q_B"], rel=1e-12)
    assert rows.min() == pytest.approx(cf["Q_D"], rel=1e-12, abs=1e-15)
    # Stripe widths: rows at the bright / dark level per flicker period (Eqs. 4, 6).
    tol = 1e-9 * cf["Q_B"]
    w_b = np.count_nonzero(rows >= cf["Q_B"] - tol) / n_periods
    w_d = np.count_nonzero(rows <= cf["Q_D"] + tol) / n_periods
    assert w_b == pytest.approx(cf["W_B"], abs=1.0)
    assert w_d == pytest.approx(cf["W_D"], abs=1.0)
    # Eq. 7: a steady light of the same average gives P, which is also the frame average.
    steady = SteadyLight(level=I_P * duty)
    p = led_rows_rgb(steady, cam, normalize=False)[:, 0] * t_e * ALPHA
    np.testing.assert_allclose(p, cf["P"], rtol=1e-12)
    whole = int(round(1 / freq_hz / t_s)) * (n_rows // int(round(1 / freq_hz / t_s)))
    assert rows[:whole].mean() == pytest.approx(cf["P"], rel=2e-3)


@pytest.mark.parametrize("light,freq_hz", [
    (PwmLight(freq_hz=400.0, duty=0.5), 400.0),
    (PwmLight(freq_hz=1234.0, duty=0.17, depth=0.6, phase_s=1e-4), 1234.0),
    (MainsFlicker(supply_hz=50.0, depth=1.0), 100.0),
    (MainsFlicker(supply_hz=60.0, depth=0.4, phase_s=2e-3), 120.0),
    (SequenceLight(compile_spec(BarcodeSpec.mono("ook", [800.0]))), 800.0),
])
@pytest.mark.parametrize("k", [1, 2, 3])
def test_exposure_of_whole_periods_is_stripe_free(light, freq_hz, k):
    """Sec. 4.1 / Fig. 1(e): t_e = N / f integrates whole periods, so every row is equal."""
    cam = CameraModel(row_time_s=1 / 50_000, n_rows=2000, exposure_s=k / freq_hz)
    rows = led_rows_rgb(light, cam, start_s=0.0377)
    assert np.ptp(rows) <= 1e-9 * rows.mean()
    # and the same light at a non-multiple exposure is striped
    cam2 = CameraModel(row_time_s=1 / 50_000, n_rows=2000, exposure_s=(k + 0.5) / freq_hz)
    assert np.ptp(led_rows_rgb(light, cam2, start_s=0.0377)) > 1e-3


def test_tone_ratio_recovered_from_noiseless_profile():
    spec = BarcodeSpec.mono("two-tone", [1000.0, 1500.0], switching_hz=200.0)
    light = SequenceLight(compile_spec(spec))
    cam = CameraModel(row_time_s=1 / 50_000, n_rows=4000, exposure_s=1 / 20_000)
    scene = np.full((cam.n_rows, 8, 3), 0.5, dtype=np.float32)
    frame = simulate_frame(light, scene, cam, rng=np.random.default_rng(0), start_s=0.0,
                           noise=False, output="linear")
    prof = frame[:, :, 1].mean(axis=1, dtype=np.float64)
    x = (prof - prof.mean()) * np.hanning(prof.size)
    n_fft = 1 << 16
    power = np.abs(np.fft.rfft(x, n_fft)) ** 2
    f_cpr = np.fft.rfftfreq(n_fft)
    peaks, _ = find_peaks(power)
    peaks = peaks[(f_cpr[peaks] > 0.005) & (f_cpr[peaks] < 0.1)]
    top = np.sort(f_cpr[peaks[np.argsort(power[peaks])[-2:]]])
    for got, want in zip(top, spec.all_freqs_hz, strict=True):
        assert abs(got - hz_to_cpr(want, row_time_s=cam.row_time_s)) < 1.5 / cam.n_rows
    assert top[1] / top[0] == pytest.approx(1.5, abs=0.01)


def test_row_values_are_sinc_filtered_for_pwm():
    """The row profile's fundamental has the closed-form amplitude of a boxcar-filtered square
    wave: |sinc(f t_e)| times the square wave's first Fourier coefficient (up to aliasing of
    harmonics 199, 201, ... onto bin 1 at 200 rows per period, ~1e-4 relative)."""
    f, duty, t_e = 500.0, 0.5, 0.00071
    light = PwmLight(freq_hz=f, duty=duty, depth=1.0, mean=1.0)
    t_s = 1 / (f * 200)  # 200 rows per period
    cam = CameraModel(row_time_s=t_s, n_rows=200 * 20, exposure_s=t_e)
    rows = led_rows_rgb(light, cam)[:, 0]
    c1 = np.abs(np.fft.rfft(rows)[20]) * 2 / rows.size
    expect = (2 / np.pi) * abs(np.sin(np.pi * duty)) * abs(np.sinc(f * t_e)) * (1 / duty)
    assert c1 == pytest.approx(expect, rel=2e-4)


def test_deterministic_for_a_seed():
    spec = BarcodeSpec.rgb("rgb", [400, 600, 800], [1000, 1200, 1400], [1600, 1800, 2000])
    light = SequenceLight(compile_spec(spec))
    cam = CameraModel(row_time_s=1 / 60_000, n_rows=120, exposure_s=1 / 3000)
    scene = np.random.default_rng(1).uniform(0.1, 0.9, (120, 160, 3)).astype(np.float32)
    a = simulate_frame(light, scene, cam, rng=np.random.default_rng(7))
    b = simulate_frame(light, scene, cam, rng=np.random.default_rng(7))
    c = simulate_frame(light, scene, cam, rng=np.random.default_rng(8))
    assert a.dtype == np.uint8 and a.shape == (120, 160, 3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
