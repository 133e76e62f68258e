"""MkDocs hook: the index page shows the README's sections, read from the README at build time.

``<!-- readme-section: Quick start -->`` in ``docs/index.md`` becomes the README's section of
that title (its heading included), so the site's quick start is the README's and cannot drift;
the README's links into ``docs/`` are rewritten to the site's pages. A title the README lacks
fails the build.
"""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"
MARKER = re.compile(r"<!-- readme-section: (.+?) -->")


def readme_section(title: str, readme: str) -> str:
    """The README's ``## title`` section, up to the next second-level heading."""
    match = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", readme, re.M | re.S)
    if match is None:
        raise ValueError(f"docs/index.md includes README section {title!r}; the README has none")
    return match.group(0).rstrip() + "\n"


def site_links(markdown: str) -> str:
    """The README's links into ``docs/`` as links between the site's pages."""
    return re.sub(r"\]\(docs/", "](", markdown)


def on_page_markdown(markdown: str, page, **_: object) -> str:
    if page.file.src_uri != "index.md":
        return markdown
    readme = README.read_text(encoding="utf-8")
    return MARKER.sub(lambda m: site_links(readme_section(m.group(1), readme)), markdown)
