"""Issue #33 item 6: the README's sample output is what `detect` prints for the demo images
now (timings masked), so a change of the detector's numbers shows up as a failing test until
`make docs` regenerates it."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "scripts") not in sys.path:
    sys.path.insert(0, str(ROOT / "scripts"))

make_docs = pytest.importorskip("make_docs")


def test_mask_timings_and_blocks_round_trip():
    text = "a\n<!-- x:begin (generated) -->\nold 12.5 ms\n<!-- x:end -->\nb\n"
    assert make_docs.read_block(text, "x") == "old 12.5 ms\n"
    new = make_docs.replace_block(text, "x", "new 3 ms\n")
    assert make_docs.read_block(new, "x") == "new 3 ms\n" and new.endswith("b\n")
    assert make_docs.mask_timings("decode 12.3 ms (total 1,0 ms)") == "decode N ms (total 1,N ms)"


def test_readme_sample_output_matches_a_fresh_run(tmp_path):
    pytest.importorskip("synth")
    make_docs.write_demo_images(tmp_path)
    output, status = make_docs.run_detect(tmp_path)
    fresh = make_docs.mask_timings(make_docs.sample_block(output, status))
    readme = make_docs.mask_timings(make_docs.read_block(make_docs.README.read_text(),
                                                         "sample-output"))
    assert readme == fresh, ("README's sample output differs from what `detect` prints now: "
                             "run `make docs`")


def test_readme_figure_captions_follow_the_deciding_stage(tmp_path):
    pytest.importorskip("synth")
    make_docs.write_demo_images(tmp_path)
    assert make_docs.read_block(make_docs.README.read_text(), "figure-captions") == \
        make_docs.captions_block(tmp_path), "README's figure captions are stale: run `make docs`"


def test_design_doc_figure_captions_are_generated_too(tmp_path):
    """Issue 41: design.md's "Reading the figure" described the old three panels; its captions
    are now the generated block (with the page's own link to the clean figure)."""
    pytest.importorskip("synth")
    make_docs.write_demo_images(tmp_path)
    assert make_docs.read_block(make_docs.DESIGN_DOC.read_text(), "figure-captions") == \
        make_docs.captions_block(tmp_path, make_docs.DESIGN_DOC), \
        "design.md's figure captions are stale: run `make docs`"


def test_every_image_the_docs_show_is_known_and_present():
    """`make docs --check` knows what makes every image the docs show (issue 41: the reviewer
    screenshot and design.md's figures were stale and nothing checked them)."""
    assert make_docs.figure_problems({}) == []
    shown = make_docs.doc_images()
    assert {"verdict_protected.png", "review_page.png"} <= set(shown)
    assert {f.name for f in make_docs.FIGURES_SHOWN} >= set(shown)


def test_verdict_figures_match_a_fresh_rendering(tmp_path):
    pytest.importorskip("synth")
    make_docs.write_demo_images(tmp_path)
    (tmp_path / "figs").mkdir()
    made = make_docs.render_verdict_figures(tmp_path, tmp_path / "figs")
    assert set(made) == {"verdict_protected.png", "verdict_clean.png"}
    assert make_docs.figure_problems(made) == []


def test_a_changed_figure_is_reported(tmp_path):
    from PIL import Image

    fresh = tmp_path / "verdict_clean.png"
    Image.open(make_docs.FIGURES / "verdict_clean.png").convert("L").convert("RGB").rotate(
        180).save(fresh)
    (problem,) = make_docs.figure_problems({"verdict_clean.png": fresh})
    assert "verdict_clean.png differs from a fresh rendering" in problem
