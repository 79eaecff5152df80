"""MkDocs hook: the pages' formulas as MathML, converted when the site is built, so the maths needs no script and
loads nothing from outside the site (browsers render MathML themselves).

``pymdownx.arithmatex`` in generic mode (mkdocs.yml) leaves each formula HTML-escaped, as
``<span class="arithmatex">\\(...\\)</span>`` (inline, ``$...$``) or ``<div class="arithmatex">\\[...\\]</div>``
(display, ``$$...$$``). :func:`on_page_content` converts each with ``latex2mathml`` and keeps the wrapper (the
theme styles ``div.arithmatex``). A formula that does not convert cleanly fails the build, naming the page and the
formula: latex2mathml raises on malformed input, but passes an unknown command through as its name
(``<mi>\\foo</mi>``) and an ``&`` outside a table as a bare ``&`` (not XML); both are caught here.
"""

from __future__ import annotations

import html
import re
from xml.etree import ElementTree

from latex2mathml.converter import convert
from mkdocs.exceptions import PluginError

_FORMULA = re.compile(r'<(?P<tag>span|div) class="arithmatex">\s*\\[(\[](?P<tex>.*?)\\[)\]]\s*</(?P=tag)>', re.DOTALL)
_LEFT_OVER = re.compile(r'class="arithmatex">\s*\\[(\[]')


def to_mathml(tex: str, display: bool) -> str:
    """LaTeX (unescaped) -> one ``<math>`` element; ValueError when latex2mathml cannot convert it faithfully."""
    try:
        mathml = convert(tex, display="block" if display else "inline")
    except Exception as error:  # latex2mathml raises its own exception types (and IndexError, KeyError, ...)
        raise ValueError(f"latex2mathml failed ({type(error).__name__}: {error})") from error
    try:
        root = ElementTree.fromstring(mathml)
    except ElementTree.ParseError as error:
        raise ValueError(f"latex2mathml gave malformed MathML ({error}): {mathml}") from error
    unknown = sorted({text for text in root.itertext() if "\\" in text})
    if unknown:
        raise ValueError(f"unsupported LaTeX: {', '.join(unknown)}")
    return mathml


def _replace(match: re.Match, where: str) -> str:
    tag = match["tag"]
    tex = html.unescape(match["tex"]).strip()
    try:
        mathml = to_mathml(tex, display=tag == "div")
    except ValueError as error:
        raise PluginError(f"{where}: formula {tex!r} does not convert to MathML: {error}") from error
    return f'<{tag} class="arithmatex">{mathml}</{tag}>'


def on_page_content(html_text: str, page, config, files) -> str:
    """Every arithmatex formula of the page as MathML."""
    where = page.file.src_uri
    converted = _FORMULA.sub(lambda match: _replace(match, where), html_text)
    left = _LEFT_OVER.search(converted)
    if left:
        raise PluginError(f"{where}: a formula was left unconverted: {converted[left.start():][:200]!r}")
    return converted
