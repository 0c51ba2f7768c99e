"""What the detector assumes about an LED it did not build: the emitter family of a policy.

A policy states ratio sets (tones up to a common scale), M tones per channel and on-off
keying; everything else belongs to whoever built the LED. The detector therefore searches,
for every spec, over:

- the switching rate f_B, from `MIN_SWITCHING_HZ` (below the 200 Hz of the paper's detection
  experiments, Sec. 7.3) up to f_1 / `MIN_CYCLES_PER_SLOT` (a little above the f_B = f_1 of its
  flicker-free design, Sec. 3.3.1). Our own firmware's flicker rule (f_B / M >= 80 Hz) is not
  assumed. In templates this is the range of c_1 = f_1 / f_B, cycles of f_1 per slot;
- the slot order: every cyclic class of permutations of the tones (a cyclic shift of an order
  is the same pattern seen from another slot, which the phase search covers);
- the tone phase at a slot boundary: restarted with the slot, or running on continuously.

Duty about 0.5 and LED rise/fall times of a few per cent of a half-period are absorbed by the
exposure smoothing the fits already search.
"""

from __future__ import annotations

import itertools
from dataclasses import replace
from functools import lru_cache

from lishield_guard.spec import BarcodeSpec

__all__ = ["MIN_CYCLES_PER_SLOT", "MIN_SWITCHING_HZ", "cycles_range", "emitter_variants",
           "phase_mode", "variant_label"]

MIN_SWITCHING_HZ = 160.0  # Hz; the paper's Sec. 7.3 plays 200 Hz, a 20 % margin below it
MIN_CYCLES_PER_SLOT = 0.8  # c_1 floor: f_B up to 1.25 f_1 (the paper's design is f_B = f_1)


def cycles_range(f1_hz: float) -> tuple[float, float]:
    """Range of c_1 = f_1 / f_B (cycles of the lowest tone per slot, unitless) searched for a
    spec whose lowest tone is ``f1_hz``: [`MIN_CYCLES_PER_SLOT`, f_1 / `MIN_SWITCHING_HZ`]."""
    return MIN_CYCLES_PER_SLOT, max(MIN_CYCLES_PER_SLOT * 1.25, f1_hz / MIN_SWITCHING_HZ)


def phase_mode(spec: BarcodeSpec) -> str:
    """``"restart"`` (each slot restarts its tone at an ON edge) or ``"continuous"``."""
    return str(getattr(spec, "phase", "restart"))


def _cyclic_classes(m: int) -> list[tuple[int, ...]]:
    """One representative (starting with tone 0) of each cyclic class of permutations of m."""
    return [(0, *rest) for rest in itertools.permutations(range(1, m))]


@lru_cache(maxsize=64)
def emitter_variants(spec: BarcodeSpec, *, max_variants: int = 8) -> tuple[BarcodeSpec, ...]:
    """The spec as other LEDs may play it: every cyclic slot-order class x both phase modes.

    The spec itself comes first. Specs whose tones cannot be reordered or re-phased (M = 1),
    or whose BarcodeSpec has no ``phase`` field, yield fewer variants. At most
    ``max_variants`` are returned (M <= 4 gives at most 12 orders; the ascending and the
    reversed order classes come first).
    """
    m = spec.n_tones
    orders = _cyclic_classes(m) if m > 1 else [(0,)]
    orders.sort(key=lambda o: (o != tuple(range(m)), o != (0, *range(m - 1, 0, -1)), o))
    has_phase = hasattr(spec, "phase")
    phases = ("restart", "continuous") if has_phase else ("restart",)
    out: list[BarcodeSpec] = [spec]
    for order in orders:
        for ph in phases:
            try:
                kw = {"order": order} if order != tuple(range(m)) else {"order": "cyclic"}
                if has_phase:
                    kw["phase"] = ph
                v = replace(spec, **kw)
            except Exception:  # a spec type without explicit orders: ascending only
                continue
            if all(v.slot_order() != o.slot_order() or phase_mode(v) != phase_mode(o)
                   for o in out):
                out.append(v)
            if len(out) >= max_variants:
                return tuple(out)
    return tuple(out)


def variant_label(spec: BarcodeSpec) -> str:
    """Short description of how a variant plays its tones, e.g. ``"order 0-2-1, restart"``."""
    return f"order {'-'.join(str(i) for i in spec.slot_order())}, {phase_mode(spec)}"
