"""The README and the documentation pages: what a newcomer reads first, and links that lead somewhere.

The site itself is built by ``make docs`` (Sphinx, warnings as errors), which CI runs after the tests.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: the Markdown pages a reader opens on GitHub or on the site (the build's output and generated pages aside)
PAGES = [README] + sorted(
    path for path in (ROOT / "docs").rglob("*.md") if "_build" not in path.parts and "_generated" not in path.parts
)
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _section(text: str, title: str) -> str:
    """The text of the ``## title`` section of a Markdown page."""
    match = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text, re.S | re.M)
    assert match, f"no section '## {title}'"
    return match.group(1)


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, re.S)


def test_readme_is_short_and_starts_with_the_two_commands():
    lines = README.read_text().splitlines()
    assert len(lines) <= 150, f"README.md has {len(lines)} lines: the details belong in docs/"
    top = "\n".join(lines[:15])
    assert "make demo" in top and "make test" in top


@pytest.mark.parametrize("page", [README, ROOT / "docs" / "guide" / "quickstart.md"], ids=lambda p: p.name)
def test_the_quick_start_to_copy_is_cpu_sized(page):
    """The first code block of the quick start finishes in minutes on a CPU; URLB's size is the GPU line."""
    text = page.read_text()
    blocks = _python_blocks(_section(text, "Quick start") if page == README else text)
    first = blocks[0]
    hidden = [int(h) for h in re.findall(r"hidden_dim=(\d+)", first)]
    batches = [int(b) for b in re.findall(r"batch_size=(\d+)", first)]
    steps = [int(s.replace("_", "")) for s in re.findall(r"\.learn\(([\d_]+)", first)]
    assert hidden and max(hidden) <= 256, "the CPU quick start must set small networks (hidden_dim <= 256)"
    assert batches and max(batches) <= 256, "the CPU quick start must set a small batch (batch_size <= 256)"
    assert steps and sum(steps) <= 50_000, f"the CPU quick start trains for {steps} steps: hours on a CPU"
    full = [block for block in blocks[1:] if "2_000_000" in block]
    assert full and all('device="cuda"' in block for block in full), "URLB's full size is shown as the GPU line"


@pytest.mark.parametrize("page", [README, ROOT / "docs" / "guide" / "quickstart.md"], ids=lambda p: p.name)
def test_the_quick_start_sets_the_threads_its_times_are_for(page):
    """The times beside the quick start are one-thread figures: the block to copy sets one thread."""
    text = page.read_text()
    first = _python_blocks(_section(text, "Quick start") if page == README else text)[0]
    assert "torch.set_num_threads(1)" in first


def test_no_page_promises_numbers_that_repeat_exactly():
    """The demo's numbers repeat on one machine with the same versions, not on every machine."""
    pages = [README, *sorted((ROOT / "docs").rglob("*.md"))]
    for page in pages:
        text = " ".join(page.read_text().split())
        assert "repeat exactly" not in text, page


def test_readme_states_no_unmeasured_gpu_estimate():
    """GPU times are the measured ones (docs/guide/speed.md), not an estimate beside them."""
    text = README.read_text() + (ROOT / "docs" / "guide" / "speed.md").read_text()
    assert "not measured yet" not in text


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_lead_to_files(page):
    """Every relative link of a page names a file or folder of the repository (GitHub shows both)."""
    broken = []
    for target in LINK.findall(page.read_text()):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        path = (page.parent / target.split("#", 1)[0]).resolve()
        if not path.exists():
            broken.append(target)
    assert not broken, f"{page.relative_to(ROOT)} links to missing files: {broken}"
