"""`lishield-guard synth`: synthetic captures and labelled datasets (imports synth lazily)."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import typer

from lishield_guard.commands import ExitCode, fail
from lishield_guard.errors import LishieldError

__all__ = ["Codec", "Negative", "Phase", "Rotation", "Subsampling", "register"]

ROTATIONS = (0, 90, 180, 270)


class Rotation(StrEnum):
    """Clockwise rotations of a capture, degrees."""

    r0 = "0"
    r90 = "90"
    r180 = "180"
    r270 = "270"


class Subsampling(StrEnum):
    """JPEG chroma subsampling."""

    s420 = "4:2:0"
    s422 = "4:2:2"
    s444 = "4:4:4"


class Phase(StrEnum):
    """Tone phase at a slot start (`BarcodeSpec.phase`)."""

    restart = "restart"
    continuous = "continuous"




def _parse_sets(values: list[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    for v in values:
        if "=" not in v:
            raise fail(f"--set expects KEY=VALUE, got {v!r}")
        k, val = v.split("=", 1)
        out[k.strip()] = val.strip()
    return out


def dataset(
    out: Path = typer.Option(..., "--out", help="Output folder (created if missing)."),
    n_pos: int = typer.Option(0, "--n-pos", help="Number of barcode captures (label 1)."),
    n_neg: int = typer.Option(0, "--n-neg", help="Number of negatives (label 0)."),
    seed: int = typer.Option(0, "--seed", help="Dataset seed; output is byte-identical per seed."),
    mix: str = typer.Option("default", "--mix", metavar="MIX",
                            help="Parameter mix: default, mono, rgb, negatives-only, easy or "
                                 "nominal "
                                 "(documented in synth/dataset.py); fields can be overridden "
                                 "with --set."),
    sets: list[str] = typer.Option([], "--set", metavar="KEY=VALUE",
                                   help="Override a mix field, e.g. --set attack_prob=0.5 or "
                                        "--set jpeg_quality_range=80,95. Repeatable."),
    size: str | None = typer.Option(None, "--size",
                                    help="Photos: 1080p (default), 720p, 8mp, 12mp or WxH. "
                                         "Videos: mixed (default: 540p/720p/1080p per clip), "
                                         "360p, 540p, 720p, 1080p or WxH."),
    videos: bool = typer.Option(False, "--videos",
                                help="Write video clips (NNNNNN.mp4) instead of photos."),
    video_mix: str = typer.Option("default", "--video-mix", metavar="VMIX",
                                  help="With --videos: default (camera motion on half the "
                                       "clips), static or motion (documented in "
                                       "synth/video.py)."),
    jobs: int = typer.Option(1, "--jobs", "-j", help="Worker processes."),
    progress: bool = typer.Option(True, "--progress/--no-progress",
                                  help="Progress bar on stderr."),
) -> None:
    """Write a labelled dataset: NNNNNN.jpg images (or .mp4 clips) plus manifest.jsonl.

    The output is byte-identical for a given seed, mix and size whatever --jobs; the
    manifest records every item's parameters (preset, exposure, ambient light, coverage,
    rotation, ...; for clips also fps, duration_s, n_frames, bitrate, codec, motion and the
    per-frame exposure and LED contrast).

    Examples:
      lishield-guard synth dataset --out eval --n-pos 400 --n-neg 400 -j 2
      lishield-guard synth dataset --out neg --n-neg 100 --mix negatives-only
      lishield-guard synth dataset --videos --out clips --n-pos 60 --n-neg 60 --seed 3401 -j 2
    """
    from synth.dataset import MIXES, parse_size, write_dataset

    try:
        if mix not in MIXES:
            raise fail(f"unknown --mix {mix!r}; known: {', '.join(MIXES)}")
        m = MIXES[mix].with_overrides(_parse_sets(sets)) if sets else MIXES[mix]
        if videos:
            from synth.video import write_video_dataset

            manifest = write_video_dataset(out, n_pos=n_pos, n_neg=n_neg, seed=seed, mix=m,
                                           size=size or "mixed", video_mix=video_mix,
                                           jobs=jobs, progress=progress)
        else:
            manifest = write_dataset(out, n_pos=n_pos, n_neg=n_neg, seed=seed, mix=m,
                                     size=parse_size(size or "1080p"), jobs=jobs,
                                     progress=progress)
    except LishieldError as exc:
        raise fail(str(exc)) from None
    except OSError as exc:
        raise fail(f"cannot write dataset: {exc}", ExitCode.ERROR) from None
    typer.echo(str(manifest))


def capture(
    preset: str = typer.Option("table1-seq1", "--preset", metavar="PRESET",
                                  help="Barcode preset: table1-seq1..3, table2-rgb, "
                                       "table3-m2..m6 (see `lishield-guard spec list`)."),
    scene: str = typer.Option("skimage:astronaut", "--scene",
                              help="Image file, skimage:NAME or texture:KIND."),
    output: Path = typer.Option(..., "-o", "--output", help="Output JPEG path."),
    row_rate_hz: float = typer.Option(60_000.0, "--row-rate-hz", help="Rows read per second."),
    exposure_s: float | None = typer.Option(None, "--exposure-s",
                                            help="Manual exposure time in seconds."),
    auto: bool = typer.Option(False, "--auto",
                              help="Auto exposure (default when --exposure-s is not given)."),
    gain: float | None = typer.Option(None, "--gain",
                                      help="Manual ISO-like gain (1 = ISO 100); default auto."),
    ambient_ratio: float = typer.Option(0.0, "--ambient-ratio",
                                        help="Steady ambient light / LED average, >= 0."),
    coverage: float = typer.Option(1.0, "--coverage",
                                   help="Lit fraction of the frame in (0, 1]; < 1 adds a "
                                        "smooth falloff around the frame centre."),
    jpeg_quality: int = typer.Option(90, "--jpeg-quality", help="JPEG quality 1-100."),
    subsampling: Subsampling = typer.Option(Subsampling.s420, "--subsampling",
                                            help="JPEG chroma subsampling."),
    downscale: float = typer.Option(1.0, "--downscale", help="Downscale factor >= 1."),
    rotate: Rotation = typer.Option(Rotation.r0, "--rotate", help="Clockwise rotation, degrees."),
    rotate_exif: bool = typer.Option(False, "--rotate-exif",
                                     help="Store the rotation as an EXIF tag, not in pixels."),
    size: str = typer.Option("1080p", "--size", help="1080p, 720p, 8mp, 12mp or WxH."),
    switching_hz: float | None = typer.Option(None, "--switching-hz",
                                              help="Override the preset's switching rate f_B."),
    phase: Phase = typer.Option(Phase.restart, "--phase", help="Tone phase at a slot start."),
    order: str | None = typer.Option(None, "--order",
                                     help="Slot order: cyclic, or tone indices like 2,1,0."),
    rise_s: float = typer.Option(0.0, "--rise-s", help="LED rise/fall time in seconds."),
    loop_patterns: int = typer.Option(1, "--loop-patterns", min=1,
                                      help="Patterns in one firmware loop (with --phase "
                                           "continuous the tones run on across them)."),
    no_noise: bool = typer.Option(False, "--no-noise", help="Disable shot and read noise."),
    seed: int = typer.Option(0, "--seed", help="Random seed (frame start and noise)."),
    plot: Path | None = typer.Option(None, "--plot",
                                     help="Also write a PNG: LED waveform, row profile, spectrum."),
) -> None:
    """Render one capture of a scene under a barcode LED.

    The LED plays the preset's firmware sequence; each row integrates it over its exposure
    exactly, then noise, sRGB, rotation and JPEG follow. The capture's parameters are printed
    on stderr.

    Examples:
      lishield-guard synth capture --scene skimage:coffee -o protected.jpg
      lishield-guard synth capture --preset table2-rgb --rotate 90 -o rgb.jpg
    """
    if exposure_s is not None and auto:
        raise fail("give either --exposure-s or --auto, not both")
    try:
        spec, light = _capture_light(preset, switching_hz, str(getattr(phase, "value", phase)),
                                     order, loop_patterns, rise_s)
        data, img, frame, camera, start_s = _render_capture(
            light, scene=scene, size=size, row_rate_hz=row_rate_hz, exposure_s=exposure_s,
            ambient_ratio=ambient_ratio, coverage=coverage, gain=gain, noise=not no_noise,
            seed=seed, downscale=downscale, rotate=int(getattr(rotate, "value", rotate)),
            rotate_exif=rotate_exif, jpeg_quality=jpeg_quality,
            subsampling=str(getattr(subsampling, "value", subsampling)))
    except LishieldError as exc:
        raise fail(str(exc)) from None
    t_e = camera.exposure_s
    try:
        output.parent.mkdir(parents=True, exist_ok=True)
        output.write_bytes(data)
        if plot is not None:
            from synth.plots import capture_plot

            capture_plot(plot, light=light, camera=camera, frame=frame, start_s=start_s)
    except OSError as exc:
        raise fail(f"cannot write output: {exc}", ExitCode.ERROR) from None
    typer.echo(f"{output} preset={spec.name} f_B={spec.f_b_hz:g}Hz phase={spec.phase} "
               f"order={','.join(map(str, spec.slot_order()))} exposure_s={t_e:.6g} "
               f"row_rate_hz={row_rate_hz:g} size={img.shape[1]}x{img.shape[0]}", err=True)


def _render_capture(light, *, scene: str, size: str, row_rate_hz: float,
                    exposure_s: float | None, ambient_ratio: float, coverage: float,
                    gain: float | None, noise: bool, seed: int, downscale: float, rotate: int,
                    rotate_exif: bool, jpeg_quality: int, subsampling: str):
    """``synth capture``'s frame: (JPEG bytes, stored pixels, linear frame, camera, start)."""
    import numpy as np

    from lishield_guard.camera import CameraModel
    from synth.camera import auto_exposure_s, encode_jpeg, postprocess, simulate_frame
    from synth.dataset import parse_size
    from synth.light import coverage_map
    from synth.scene import load_scene

    if rotate not in ROTATIONS:
        raise fail(f"--rotate must be 0, 90, 180 or 270, got {rotate}")
    if not 0.0 < coverage <= 1.0:
        raise fail(f"--coverage must be in (0, 1], got {coverage}")
    if not row_rate_hz > 0:
        raise fail(f"--row-rate-hz must be > 0, got {row_rate_hz}")
    n_rows, n_cols = parse_size(size)
    rng = np.random.default_rng(seed)
    refl = load_scene(scene, n_rows, n_cols)
    cmap = None if coverage >= 1.0 else coverage_map(n_rows, n_cols, fraction=coverage)
    t_e = exposure_s if exposure_s is not None else auto_exposure_s(
        refl, ambient_ratio=ambient_ratio, coverage=cmap)
    camera = CameraModel(row_time_s=1.0 / row_rate_hz, n_rows=n_rows, exposure_s=t_e)
    start_s = float(rng.uniform(0.0, 1.0))
    frame = simulate_frame(light, refl, camera, rng=rng, start_s=start_s,
                           ambient_ratio=ambient_ratio, coverage=cmap, gain=gain, noise=noise)
    img, orient = postprocess(frame, downscale=downscale, rotation_deg=rotate,
                              rotation_mode="exif" if rotate_exif else "bake")
    data = encode_jpeg(img, quality=jpeg_quality, subsampling=subsampling,
                       exif_orientation=orient)
    return data, img, frame, camera, start_s


def _capture_light(preset: str, switching_hz: float | None, phase: str, order: str | None,
                   loop_patterns: int, rise_s: float):
    """The spec of ``synth capture``'s options and the LED playing its firmware sequence."""
    import dataclasses

    from firmware.sequence import compile_spec
    from lishield_guard.spec import get_preset
    from synth.dataset import EMITTER_ALLOW, LED_CLOCK_HZ
    from synth.light import SequenceLight

    if order is not None and order not in ("cyclic", "random"):
        try:
            order = tuple(int(i) for i in order.split(",") if i.strip())
        except ValueError:
            raise fail(f"--order must be cyclic or comma-separated tone indices, "
                       f"got {order!r}") from None
    spec = get_preset(preset)
    if switching_hz is not None:
        spec = dataclasses.replace(spec, switching_hz=switching_hz)
    spec = dataclasses.replace(spec, phase=phase)
    if order is not None:
        spec = dataclasses.replace(spec, order=order)
    light = SequenceLight(compile_spec(spec, clock_hz=LED_CLOCK_HZ, allow=EMITTER_ALLOW,
                                       n_patterns=loop_patterns), rise_s=rise_s)
    return spec, light


class Codec(StrEnum):
    """Video codecs (`synth.video.CODECS`)."""

    h264 = "h264"
    hevc = "hevc"
    vp9 = "vp9"
    vp8 = "vp8"


class Negative(StrEnum):
    """Look-alike lights and scenes for a clean clip."""

    steady = "steady"
    mains = "mains"
    pwm = "pwm"
    texture = "texture"


def video(
    out: Path = typer.Option(..., "--out", "-o", help="Output file (.mp4, or .webm for VP8/9)."),
    preset: str | None = typer.Option(None, "--preset", metavar="PRESET",
                                      help="Barcode preset (default: drawn from the mix)."),
    f_b: float | None = typer.Option(None, "--f-b", help="Switching rate f_B in Hz "
                                     "(default: the preset's own, else drawn from the mix)."),
    negative: Negative | None = typer.Option(None, "--negative",
                                             help="A clean look-alike clip instead."),
    fps: float | None = typer.Option(None, "--fps", help="Frame rate (default 24-60 drawn)."),
    duration_s: float | None = typer.Option(None, "--duration", help="Seconds (default 2-10)."),
    size: str = typer.Option("540p", "--size", help="360p, 540p, 720p, 1080p or WxH."),
    ambient: float | None = typer.Option(None, "--ambient", help="Ambient / LED average, >= 0."),
    coverage: float | None = typer.Option(None, "--coverage",
                                          help="Lit fraction of the frame in (0, 1]."),
    exposure_s: float | None = typer.Option(None, "--exposure-s",
                                            help="Lock the exposure (s); default auto."),
    motion: bool | None = typer.Option(None, "--motion/--no-motion",
                                       help="Camera pan and shake (default: drawn, 50%)."),
    codec: Codec = typer.Option(Codec.h264, "--codec", help="Video codec."),
    bitrate: int | None = typer.Option(None, "--bitrate", help="Bit rate in bit/s."),
    rotate: Rotation | None = typer.Option(None, "--rotate",
                                           help="Clockwise display rotation, degrees."),
    rotate_pixels: bool = typer.Option(False, "--rotate-pixels",
                                       help="Bake --rotate into the pixels (default: a "
                                            "display-matrix tag, as phones write)."),
    scene: str | None = typer.Option(None, "--scene",
                                     help="Image file, skimage:NAME, photos:DIR#I or "
                                          "texture:KIND (default: drawn)."),
    seed: int = typer.Option(0, "--seed", help="Seed of every parameter not given."),
    as_json: bool = typer.Option(False, "--json", help="Print the clip's full record as one "
                                 "JSON line (per-frame exposures, light, motion) instead of "
                                 "the one-line summary."),
) -> None:
    """Render one synthetic clip: consecutive rolling-shutter frames, encoded (H.264 MP4).

    The LED runs on between frames (frame k starts k/fps after frame 0), auto exposure
    follows the scene, and the camera may pan and shake over a larger scene. A --preset
    plays at its own f_B unless --f-b says otherwise. Parameters not given are drawn from the
    default mixes with --seed; one line on stdout sums the clip up (--json: its full record).

    Examples:
      lishield-guard synth video -o clip.mp4 --preset table2-rgb --f-b 200 --duration 3
      lishield-guard synth video -o blinds.mp4 --negative texture --scene texture:blinds --motion
      lishield-guard synth video -o portrait.mp4 --rotate 90 --fps 30 --size 720p
      lishield-guard synth video -o vp9.webm --codec vp9 --negative mains --bitrate 2000000
    """
    import json

    from lishield_guard.spec import get_preset
    from synth.video import clip_params, render_video_item

    try:
        if preset is not None and f_b is None:  # the preset's own f_B, not the mix's draw
            f_b = get_preset(preset).f_b_hz
        p = clip_params(seed=seed, size=size, preset=preset, switching_hz=f_b,
                        negative=None if negative is None else str(negative.value), fps=fps,
                        duration_s=duration_s, ambient_ratio=ambient, coverage=coverage,
                        exposure_s=exposure_s, motion=motion, codec=str(codec.value),
                        bitrate=bitrate,
                        rotation_deg=None if rotate is None else int(rotate.value),
                        rotation_mode="bake" if rotate_pixels else "tag", scene=scene)
        data, rec = render_video_item(p)
    except LishieldError as exc:
        raise fail(str(exc)) from None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(data)
    except OSError as exc:
        raise fail(f"cannot write output: {exc}", ExitCode.ERROR) from None
    if as_json:
        typer.echo(json.dumps({"file": str(out), **rec}, sort_keys=True))
    else:
        typer.echo(_clip_summary(out, rec))


def _clip_summary(out: Path, rec: dict) -> str:
    """``synth video``'s line: the file and what a reader checks first (as ``synth capture``
    prints one line)."""
    what = (f"preset={rec.get('preset')} f_B={rec.get('switching_hz'):g}Hz" if rec.get("label")
            else f"look-alike={rec.get('kind')}")
    return (f"{out} {what} frames={rec.get('n_frames')} fps={rec.get('fps'):g} "
            f"duration_s={rec.get('duration_s'):g} size={rec.get('width')}x{rec.get('height')} "
            f"codec={rec.get('codec')} ambient_ratio={rec.get('ambient_ratio'):.3g} "
            f"bytes={rec.get('bytes')}")


def register(app: typer.Typer) -> None:
    """Add the ``synth`` command group (``capture``, ``video``, ``dataset``) to the CLI."""
    sub = typer.Typer(name="synth", help="Synthetic captures, clips and labelled datasets.",
                      no_args_is_help=True, add_completion=False)
    sub.command("capture")(capture)
    sub.command("video")(video)
    sub.command("dataset")(dataset)
    app.add_typer(sub, name="synth")
