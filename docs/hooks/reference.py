"""MkDocs hook: Sphinx roles and "Example::" in the docstrings, read as plain Markdown."""

from __future__ import annotations

import re

# The docstrings are written for Python's help() and Sphinx-style readers: a role such as
# :func:`~pkg.mod.name` and the "Example::" that opens a code block read as plain Markdown here.
ROLE = re.compile(r":(?:func|class|meth|mod|attr|data):<code>(~?)([\w.]+)</code>")


def on_page_content(html: str, **_: object) -> str:
    html = ROLE.sub(
        lambda m: f"<code>{m.group(2).rsplit('.', 1)[-1] if m.group(1) else m.group(2)}</code>",
        html,
    )
    return html.replace("<p>Example::</p>", "<p>Example:</p>")
