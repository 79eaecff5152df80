"""MkDocs hook: the docstrings' Sphinx roles (``:func:`x```, ``:class:`~a.b.C```) as cross-references.

gsjax's docstrings name other objects with Sphinx roles; Google-style rendering leaves them as text
(``:func:<code>x</code>``). :func:`on_page_content` turns each into an optional autoref that mkdocs-autorefs
resolves when the site is written: a link where the object is rendered somewhere in the site (its full dotted name),
else the name as code. ``~`` shows the last component only, as in Sphinx.
"""

from __future__ import annotations

import re

_ROLE = re.compile(r":(?:func|class|mod|meth|attr|data|obj|exc|const):<code>(?P<short>~?)(?P<target>[\w.]+)</code>")


def _autoref(match: re.Match) -> str:
    target = match["target"]
    shown = target.rpartition(".")[2] if match["short"] else target
    return f'<autoref identifier="{target}" optional><code>{shown}</code></autoref>'


def on_page_content(html: str, page, config, files) -> str:
    """Every rendered role of the page as an optional cross-reference."""
    return _ROLE.sub(_autoref, html)
