"""The documentation stands on its own: every relative link resolves, and every measured result is indexed."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
LINK = re.compile(r"\]\(([^)\s]+)\)")


def relative_links(page: Path) -> list[str]:
    """The page's Markdown link targets that point into the repository (no URL, no anchor-only link)."""
    return [target.split("#")[0] for target in LINK.findall(page.read_text())
            if not re.match(r"^(https?:|mailto:|#)", target)]


def markdown_pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), *sorted((ROOT / "assets").rglob("README.md"))]


def test_every_relative_link_in_the_docs_resolves():
    broken = [f"{page.relative_to(ROOT)} -> {target}" for page in markdown_pages() for target in relative_links(page)
              if not (page.parent / target).resolve().exists()]
    assert broken == []


def test_every_result_file_is_reached_from_the_results_index():
    index = RESULTS / "README.md"
    reached = {(index.parent / target).resolve() for target in relative_links(index)}
    for page in list(reached):  # one hop more: the pages the index links link their pictures
        if page.suffix == ".md" and page.is_file():
            reached |= {(page.parent / target).resolve() for target in relative_links(page)}
    files = {path.resolve() for path in RESULTS.rglob("*") if path.is_file() and path != index}
    assert sorted(str(path.relative_to(RESULTS)) for path in files - reached) == []


def test_the_readme_fits_on_a_few_screens_and_names_the_design_page():
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 160
    assert "docs/design.md" in readme and "bash scripts/test.sh" in readme and "python -m sim.evaluate" in readme


def test_no_file_cites_a_design_page_outside_the_repository():
    citing = [str(path.relative_to(ROOT)) for folder in ("seggrasp", "sim", "hardware", "assets", "bench", "tests", "docs")
              for path in (ROOT / folder).rglob("*") if path.suffix in {".py", ".md", ".yaml"}
              and "DESIGN.md" in path.read_text(errors="replace") and path.name != "test_docs.py"]
    assert citing == []
