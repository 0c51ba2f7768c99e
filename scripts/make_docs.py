"""Regenerate the docs' generated blocks, figures and screenshot from the current code, and check
them and every command the docs show.

    python scripts/make_docs.py               # blocks + every generated figure + the screenshot
    python scripts/make_docs.py --check       # exit 1 when anything is stale (nothing written)
    python scripts/make_docs.py --no-figures  # blocks only (with --check: blocks and commands)

Blocks are delimited by ``<!-- NAME:begin ... -->`` and ``<!-- NAME:end -->``:

- README's ``sample-output``: what ``lishield-guard detect demo/protected.jpg demo/clean.jpg``
  prints for the demo images of ``make run`` (`synth.demo_images`, seed 0), and its exit
  status;
- ``figure-captions`` (README and docs/design.md): what the two figures show, in the words the
  reviewer page uses (`lishield_guard.plot.figure_caption`: it follows the stage that decided);
- README's ``exit-status``: the exit statuses and the error codes leading to each
  (`lishield_guard.errors.ERROR_CODES`);
- docs/service.md's ``error-codes``: the table of every code with its HTTP status.

Every image the README or a page of docs/ shows is in `FIGURES`, with the command that makes
it. The generated ones are made again and compared with the committed file (RMS of the pixel
difference, `image_rms`): ``docs/figures/verdict_*.png`` (``detect --plot`` of the demo
images), ``fig2_model_validation.png`` (``benchmarks/fig2_model_validation.py``, about 25 s)
and the reviewer-page screenshot ``review_page.png``, taken by the headless-browser test from
the running page (needs Chromium and chromedriver; without them it is left as it is, and the
script says so). The others are records of long runs (calibration, training), kept as
written: the check says which, and that they exist. A page that shows an image `FIGURES` does
not know fails the check.

``--check`` also runs `doc_commands.command_problems`: every ``lishield-guard`` command, script,
make target and HTTP route written in the docs must exist with the options it is shown with.
``tests/test_docs_sample.py`` and ``tests/test_docs_commands.py`` run the same checks in the
suite (timings masked), and the browser test compares its screenshot with the committed one.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
SERVICE_DOC = ROOT / "docs" / "service.md"
DESIGN_DOC = ROOT / "docs" / "design.md"
FIGURES = ROOT / "docs" / "figures"
FIGURE_RMS_TOL = 4.0  # RMS of the pixel difference (0-255) still "the same": two renderings
#                       of the same code on one machine differ by 0.0; an outdated figure by 10+
DEMO_ARGS = ("demo/protected.jpg", "demo/clean.jpg")
EXIT_MEANING = {0: "every image is clean", 1: "one image is protected",
                2: "a usage error", 3: "an image could not be screened"}
_MS = re.compile(r"\d+(?:\.\d+)? ms")


def _begin(name: str) -> re.Pattern:
    return re.compile(rf"<!-- {re.escape(name)}:begin[^>]*-->\n")


def read_block(text: str, name: str) -> str:
    """The content between the ``name`` markers of ``text``.

    Raises
    ------
    KeyError
        When the markers are missing.
    """
    m = _begin(name).search(text)
    end = text.find(f"<!-- {name}:end -->", m.end() if m else 0)
    if m is None or end < 0:
        raise KeyError(f"README has no generated block {name!r}")
    return text[m.end():end]


def replace_block(text: str, name: str, content: str) -> str:
    """``text`` with the ``name`` block's content replaced (markers kept)."""
    m = _begin(name).search(text)
    end = text.find(f"<!-- {name}:end -->", m.end() if m else 0)
    if m is None or end < 0:
        raise KeyError(f"README has no generated block {name!r}")
    return text[:m.end()] + content + text[end:]


def mask_timings(text: str) -> str:
    """Timings vary from run to run: every ``<number> ms`` becomes ``N ms``."""
    return _MS.sub("N ms", text)


def write_demo_images(folder: Path) -> tuple[Path, Path]:
    """The demo images of ``make run`` under ``folder/demo`` (protected, clean)."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from synth import demo_images

    return demo_images(folder / "demo", seed=0)


def _cli() -> list[str]:
    exe = Path(sys.executable).with_name("lishield-guard")
    if exe.exists():
        return [str(exe)]
    return [sys.executable, "-m", "lishield_guard.cli"]


def run_detect(folder: Path, *extra: str) -> tuple[str, int]:
    """``lishield-guard detect demo/protected.jpg demo/clean.jpg`` run in ``folder``: (stdout,
    exit status)."""
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    res = subprocess.run([*_cli(), "detect", *DEMO_ARGS, *extra], cwd=folder, env=env,
                         capture_output=True, text=True, timeout=600, check=False)
    if res.returncode not in EXIT_MEANING:
        raise RuntimeError(f"detect failed ({res.returncode}): {res.stderr}")
    return res.stdout, res.returncode


def sample_block(output: str, exit_status: int) -> str:
    """The README's sample-output block for ``detect``'s ``output`` and ``exit_status``."""
    return ("```\nlishield-guard detect " + " ".join(DEMO_ARGS) + "\n```\n\n```\n"
            + output.rstrip("\n") + "\n```\n\n"
            "(Generated by `make docs` from this README's code; the timings are those of the\n"
            f"machine that ran it. Exit status {exit_status}: {EXIT_MEANING[exit_status]}.)\n")


def captions_block(folder: Path, page: Path = README) -> str:
    """The captions of the demo figures, from their verdicts (`figure_caption`), as ``page``
    (the README or docs/design.md) links the clean one."""
    import os.path

    import lishield_guard
    from lishield_guard.plot import figure_caption

    prot = figure_caption(lishield_guard.detect(folder / "demo" / "protected.jpg"))
    clean = figure_caption(lishield_guard.detect(folder / "demo" / "clean.jpg"))
    link = os.path.relpath(FIGURES / "verdict_clean.png", page.parent)
    return f"{prot}\n\nThe figure of the clean photo ([{link}]({link})): {clean}\n"


def code_blocks() -> dict[Path, dict[str, str]]:
    """The generated blocks that need no detection: file -> block name -> content."""
    from lishield_guard.errors import error_code_table_markdown, exit_status_table_markdown

    return {README: {"exit-status": exit_status_table_markdown()},
            SERVICE_DOC: {"error-codes": error_code_table_markdown()}}


@dataclass(frozen=True)
class DocFigure:
    """An image the docs show and how it is kept true.

    Attributes
    ----------
    name : str
        File name under docs/figures.
    made_by : str
        The command that makes it.
    regenerated : bool
        True when `make docs` makes it again (and ``--check`` compares); False for the record
        of a long run (a calibration, a training), kept as written.
    """

    name: str
    made_by: str
    regenerated: bool = True


FIGURES_SHOWN = (
    DocFigure("verdict_protected.png", "lishield-guard detect demo/protected.jpg --plot FILE"),
    DocFigure("verdict_clean.png", "lishield-guard detect demo/clean.jpg --plot FILE"),
    DocFigure("review_page.png", "LISHIELD_SCREENSHOT_DIR=DIR pytest "
              "tests/service/test_review_page.py -k headless (the page after an upload)"),
    DocFigure("fig2_model_validation.png",
              "python benchmarks/fig2_model_validation.py --out FILE"),
    DocFigure("calibration_detection_by_kind.png", "lishield-guard calibrate (its report: the "
              "shipped config's calibration, docs/calibration.md)", regenerated=False),
    DocFigure("calibration_roc.png", "lishield-guard calibrate (its report: the shipped "
              "config's calibration, docs/calibration.md)", regenerated=False),
    DocFigure("calibration_heatmaps.png", "lishield-guard calibrate --profile cascade (the "
              "cascade's calibration of 2026-11-25, docs/calibration.md)", regenerated=False),
    DocFigure("training_curves_roc.png", "make train (python -m training.report, "
              "docs/training.md)", regenerated=False),
)
_IMAGE_LINK = re.compile(r"\]\(([^)\s]+\.(?:png|jpe?g|gif|svg|webp))\)", re.I)


def doc_images() -> dict[str, list[str]]:
    """Every image the README and docs/*.md show or link to: file name under docs/figures ->
    the pages that show it (an image elsewhere is named by its path from the repository)."""
    shown: dict[str, list[str]] = {}
    for page in (README, *sorted((ROOT / "docs").glob("*.md"))):
        for link in _IMAGE_LINK.findall(page.read_text(encoding="utf-8")):
            target = (page.parent / link).resolve()
            name = target.name if target.parent == FIGURES else str(target.relative_to(ROOT))
            shown.setdefault(name, []).append(page.name)
    return shown


def image_rms(a: Path, b: Path) -> float | None:
    """RMS of the pixel difference of two images (0-255 scale); None when their sizes differ
    (`matplotlib.testing.compare.calculate_rms`)."""
    import numpy as np
    from matplotlib.testing.compare import calculate_rms
    from PIL import Image

    pa, pb = (np.asarray(Image.open(x).convert("RGB"), dtype=np.int16) for x in (a, b))
    return None if pa.shape != pb.shape else float(calculate_rms(pa, pb))


def render_verdict_figures(folder: Path, out: Path) -> dict[str, Path]:
    """``detect --plot`` of the demo images in ``folder`` into ``out``/verdict_*.png (one
    ``detect`` of both, into a folder: one IMG-stem.png each)."""
    plots = out / "plots"
    subprocess.run([*_cli(), "detect", *DEMO_ARGS, "--plot", str(plots)], cwd=folder,
                   capture_output=True, timeout=600, check=False)
    made = {}
    for name in ("protected", "clean"):
        if not (plots / f"{name}.png").exists():
            raise RuntimeError(f"no figure written for demo/{name}.jpg")
        made[f"verdict_{name}.png"] = (plots / f"{name}.png").rename(out / f"verdict_{name}.png")
    return made


def render_fig2(out: Path) -> dict[str, Path]:
    """`benchmarks/fig2_model_validation.py` into ``out`` (about 25 s)."""
    png = out / "fig2_model_validation.png"
    subprocess.run([sys.executable, str(ROOT / "benchmarks" / "fig2_model_validation.py"),
                    "--out", str(png)], cwd=ROOT, capture_output=True, timeout=600,
                   check=False)
    if not png.exists():
        raise RuntimeError("benchmarks/fig2_model_validation.py wrote no figure")
    return {png.name: png}


def review_screenshot(out: Path) -> dict[str, Path]:
    """The reviewer page's screenshot, taken by the headless-browser test with
    ``LISHIELD_SCREENSHOT_DIR=out`` (needs Chromium and chromedriver; without them nothing is
    taken, and that is said)."""
    if not shutil.which("chromedriver"):
        print("review_page.png: not taken (no chromedriver/Chromium installed)",
              file=sys.stderr)
        return {}
    env = dict(os.environ, LISHIELD_SCREENSHOT_DIR=str(out))
    subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                    "tests/service/test_review_page.py", "-k", "headless"], cwd=ROOT, env=env,
                   capture_output=True, timeout=600, check=False)
    shot = out / "review_page.png"
    return {shot.name: shot} if shot.exists() else {}


def render_figures(folder: Path, out: Path) -> dict[str, Path]:
    """Every regenerated figure of `FIGURES_SHOWN`, made into ``out``."""
    return {**render_verdict_figures(folder, out), **render_fig2(out), **review_screenshot(out)}


def figure_problems(made: dict[str, Path]) -> list[str]:
    """Why the docs' images are stale: an image no entry of `FIGURES_SHOWN` knows, a missing
    file, or a regenerated figure (``made``: name -> fresh rendering) that differs from the
    committed one by more than `FIGURE_RMS_TOL`."""
    known = {f.name: f for f in FIGURES_SHOWN}
    problems = []
    for name, pages in doc_images().items():
        if name not in known:
            problems.append(f"{name} (shown in {', '.join(sorted(set(pages)))}) is not in "
                            f"make_docs.FIGURES_SHOWN: say what makes it")
        elif not (FIGURES / name).exists():
            problems.append(f"{name} is missing: {known[name].made_by}")
    for name, fresh in made.items():
        rms = image_rms(fresh, FIGURES / name) if (FIGURES / name).exists() else None
        if rms is None or rms > FIGURE_RMS_TOL:
            shown = "another size" if rms is None else f"RMS {rms:.1f} > {FIGURE_RMS_TOL}"
            problems.append(f"{name} differs from a fresh rendering ({shown}): run `make docs`")
    return problems


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true",
                    help="exit 1 when a block (timings masked), a figure, the screenshot or a "
                         "documented command is stale; nothing is written")
    ap.add_argument("--no-figures", action="store_true",
                    help="blocks only (no figure is made or compared)")
    args = ap.parse_args(argv)
    if str(ROOT / "scripts") not in sys.path:
        sys.path.insert(0, str(ROOT / "scripts"))
    from doc_commands import command_problems

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        write_demo_images(folder)
        output, status = run_detect(folder)
        files = code_blocks()
        files[README]["sample-output"] = sample_block(output, status)
        files[README]["figure-captions"] = captions_block(folder)
        files.setdefault(DESIGN_DOC, {})["figure-captions"] = captions_block(folder, DESIGN_DOC)
        stale = []
        for path, blocks in files.items():
            text = path.read_text()
            for name, block in blocks.items():
                if mask_timings(read_block(text, name)) != mask_timings(block):
                    stale.append(f"generated block {path.name}: {name} is stale: run "
                                 f"`make docs`")
                text = replace_block(text, name, block)
            if not args.check:
                path.write_text(text)
        if args.check:
            made = {}
            if not args.no_figures:
                (folder / "figures").mkdir()
                made = render_figures(folder, folder / "figures")
            problems = stale + figure_problems(made) + command_problems()
            for line in problems:
                print(line, file=sys.stderr)
            for f in FIGURES_SHOWN:
                if not f.regenerated:
                    print(f"{f.name}: a record, kept as written ({f.made_by})")
            return 1 if problems else 0
        print(f"regenerated: {', '.join(stale) or 'no block changed'}")
        if not args.no_figures:
            for name, fresh in render_figures(folder, folder).items():
                shutil.copyfile(fresh, FIGURES / name)
                print(f"docs/figures/{name} written")
    return 0


if __name__ == "__main__":
    sys.exit(main())
