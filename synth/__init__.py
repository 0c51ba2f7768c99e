"""Synthetic LiShield captures: LED light -> rolling-shutter camera -> images and datasets."""

from __future__ import annotations

from synth.camera import (
    SensorModel,
    encode_jpeg,
    led_rows_rgb,
    postprocess,
    render_linear,
    simulate_frame,
    simulate_video,
)
from synth.dataset import MIXES, Mix, demo_images, write_dataset
from synth.light import (
    MainsFlicker,
    PwmLight,
    SequenceLight,
    SteadyLight,
    coverage_map,
    row_means,
)
from synth.scene import load_scene, random_scene, texture_scene

__all__ = [
    "MIXES",
    "MainsFlicker",
    "Mix",
    "PwmLight",
    "SensorModel",
    "SequenceLight",
    "SteadyLight",
    "coverage_map",
    "demo_images",
    "encode_jpeg",
    "led_rows_rgb",
    "load_scene",
    "postprocess",
    "random_scene",
    "render_linear",
    "row_means",
    "simulate_frame",
    "simulate_video",
    "texture_scene",
    "write_dataset",
]
