"""The API reference's docstrings (issue 40): every object that the pages of docs/reference/api/ render says what
it takes and what it returns, in the Google style that mkdocstrings parses.

The objects are found as mkdocstrings finds them: griffe loads gsjax statically (no import, as the site build does)
and, from each ``::: identifier`` of those pages, the walk follows what the handler renders with the site's options
(mkdocs.yml): members whose name does not start with ``_``, not inherited, and an imported one only where it is public
(listed in its module's ``__all__``); classes and functions, recursively, and properties.

The rule, applied uniformly to each of them:

* a docstring;
* a function or method with parameters (``self`` / ``cls`` aside) names each of them in ``Args:`` (``*args`` /
  ``**kwargs`` with or without their stars), and names nothing else;
* a function or method whose return annotation is not ``None`` (a property aside) has a ``Returns:`` or ``Yields:``
  section; an item of it that griffe reads as named (``name: text``) has a lower-case name: ``A :class:`X`` ...``
  would render "A" as the name;
* a class with an ``__init__`` of its own (not generated: dataclasses and NamedTuples aside) names ``__init__``'s
  parameters in its ``Args:`` (``__init__`` itself is not rendered);
* a dataclass or NamedTuple names each field in its ``Attributes:``, one field per entry (griffe renders
  ``a, b: text`` as the name ``a,`` of type ``b``);
* a ``Returns:`` section is one item, or named items (a tuple): a continuation line at the item's indent would render
  as a row of its own; no item starts with a role (``:class:`X```: its colon is read as a separator);
* the docstring parses without a griffe warning (those fail ``mkdocs build --strict``; a ``Raises:`` continuation line
  at the item's indent is one).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from pathlib import Path

import griffe
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = ROOT / "docs" / "reference" / "api"


def documented_identifiers() -> list[str]:
    """The ``::: identifier`` directives of the API reference pages, in page order."""
    found = []
    for page in sorted(PAGES.glob("*.md")):
        found += re.findall(r"^:::\s*(\S+)", page.read_text(), flags=re.MULTILINE)
    return found


@pytest.fixture(scope="module")
def collection() -> griffe.ModulesCollection:
    loader = griffe.GriffeLoader(search_paths=[str(ROOT)], docstring_parser=griffe.Parser.google,
                                 extensions=griffe.load_extensions())
    loader.load("gsjax")
    loader.resolve_aliases(external=False, implicit=False)
    return loader.modules_collection


def rendered(obj: griffe.Object) -> Iterator[griffe.Object]:
    """``obj`` and, for a module or class, the classes, functions and properties rendered under it."""
    yield obj
    if not (obj.is_module or obj.is_class):
        return
    for member in obj.members.values():
        if member.name.startswith("_") or (member.is_imported and not member.is_public):
            continue
        target = member.final_target if member.is_alias else member
        if target.is_class or target.is_function:
            yield from rendered(target)
        elif target.is_attribute and "property" in target.labels:
            yield target


def parse(obj: griffe.Object) -> tuple[list[griffe.DocstringSection], list[str]]:
    """The sections of ``obj``'s docstring and griffe's warnings while parsing it."""
    messages: list[str] = []

    class Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            messages.append(record.getMessage())

    handler, logger = Collect(level=logging.WARNING), logging.getLogger("griffe")
    level = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.WARNING)  # whatever else configured: griffe's warnings are what fails the site build
    try:
        sections = obj.docstring.parse(griffe.Parser.google) if obj.docstring else []
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
    return sections, messages


def section_names(sections: list[griffe.DocstringSection], kind: griffe.DocstringSectionKind) -> list[str]:
    return [item.name for section in sections if section.kind is kind for item in section.value]


def is_named_tuple(cls: griffe.Class) -> bool:
    return any(str(base).split(".")[-1] == "NamedTuple" for base in cls.bases)


def fields(cls: griffe.Class) -> list[str]:
    """The fields of a dataclass or NamedTuple: its annotated attributes (properties and ClassVars aside)."""
    return [
        name for name, member in cls.members.items()
        if not name.startswith("_") and not member.is_alias and member.is_attribute and "property" not in member.labels
        and member.annotation is not None and "ClassVar" not in str(member.annotation)
    ]


def signature_parameters(function: griffe.Function, bound: bool) -> list[str]:
    names = [p.name for p in function.parameters]
    return names[1:] if bound and names else names


def problems(obj: griffe.Object) -> list[str]:
    """What ``obj``'s docstring misses under the rule of this module's docstring."""
    if not obj.docstring or not obj.docstring.value.strip():
        return ["no docstring"]
    found = []
    sections, warnings = parse(obj)
    found += [f"griffe: {message}" for message in warnings]
    args = [name.lstrip("*") for name in section_names(sections, griffe.DocstringSectionKind.parameters)]
    expected: list[str] | None = None
    if obj.is_function:
        bound = obj.parent is not None and obj.parent.is_class and "staticmethod" not in obj.labels
        expected = signature_parameters(obj, bound)
        if obj.returns is not None and str(obj.returns) != "None":
            outputs = [section for section in sections
                       if section.kind in (griffe.DocstringSectionKind.returns, griffe.DocstringSectionKind.yields)]
            if not outputs:
                found.append(f"returns {obj.returns} but has no Returns: section")
            for section in outputs:
                found += [f"a Returns: item read as named {item.name!r} (prose starting 'Word :' or 'Word:')"
                          for item in section.value if item.name and not item.name[0].islower()]
                unnamed = [item for item in section.value if not item.name]
                if len(section.value) > 1 and unnamed:
                    found.append(f"Returns: read as {len(section.value)} items, {len(unnamed)} unnamed (a continuation "
                                 "line at the item's indent starts a new item: indent it deeper)")
                found += [f"a Returns: item starts with a role that loses its colon ({item.description[:30]!r})"
                          for item in section.value if re.match(r"(class|func|mod|meth|attr|data|obj|exc):`",
                                                                item.description)]
    elif obj.is_class:
        init = obj.members.get("__init__")
        generated = "dataclass" in obj.labels or is_named_tuple(obj)
        if init is not None and not init.is_alias and init.is_function and not generated:
            expected = signature_parameters(init, bound=True)
        if generated:
            attributes = section_names(sections, griffe.DocstringSectionKind.attributes)
            found += [f"Attributes: entry {name!r} names several fields (one per entry)"
                      for name in attributes if name.endswith(",")]
            found += [f"field {name!r} not in Attributes:" for name in fields(obj) if name not in attributes]
    if expected is not None:
        found += [f"parameter {name!r} not in Args:" for name in expected if name not in args]
        found += [f"Args: names {name!r}, not a parameter" for name in args if name not in expected]
    return found


def test_every_rendered_object_says_what_it_takes_and_returns(collection):
    checked = [obj for identifier in documented_identifiers() for obj in rendered(collection[identifier])]
    assert len(checked) > 140, f"the walk saw only {len(checked)} objects"
    offenders = [f"{obj.path}: {problem}" for obj in checked for problem in problems(obj)]
    assert not offenders, f"{len(offenders)} docstring gaps:\n" + "\n".join(offenders)


GAPS = '''
"""A module."""
import dataclasses
from typing import NamedTuple


def bare(x: int) -> int:
    pass


def no_args(x: int, y: int) -> None:
    """Does something.

    Args:
      x: documented.
      z: not a parameter.
    """


def no_returns(x: int) -> int:
    """Something.

    Args:
      x: documented.
    """


def misread_returns() -> int:
    """Something.

    Returns:
      A :class:`int`.
    """


def split_returns() -> int:
    """Something.

    Returns:
      :class:`int` that goes on
      over a second line at the same indent.
    """


@dataclasses.dataclass
class Fields:
    """Fields.

    Attributes:
      a, b: grouped.
    """

    a: int
    b: int
    c: int


class Tuple(NamedTuple):
    """A tuple with no Attributes section."""

    x: int


class Made:
    """Made with arguments it does not name."""

    def __init__(self, size: int):
        self.size = size

    def method(self, scale: float) -> float:
        """Scaled.

        Returns:
          size * scale.
        """
'''


def test_the_check_finds_each_kind_of_gap(tmp_path):
    module = griffe.visit("gaps", tmp_path / "gaps.py", GAPS, docstring_parser=griffe.Parser.google,
                          extensions=griffe.load_extensions())
    found = {obj.name: problems(obj) for obj in rendered(module)}
    assert found["gaps"] == []
    assert found["bare"] == ["no docstring"]
    assert "parameter 'y' not in Args:" in found["no_args"] and "Args: names 'z', not a parameter" in found["no_args"]
    assert found["no_returns"] == ["returns int but has no Returns: section"]
    assert any("read as named 'A'" in p for p in found["misread_returns"])
    assert any("read as 2 items, 2 unnamed" in p for p in found["split_returns"])
    assert any("starts with a role" in p for p in found["split_returns"])
    assert "Attributes: entry 'a,' names several fields (one per entry)" in found["Fields"]
    assert "field 'c' not in Attributes:" in found["Fields"]
    assert found["Tuple"] == ["field 'x' not in Attributes:"]
    assert found["Made"] == ["parameter 'size' not in Args:"]
    assert found["method"] == ["parameter 'scale' not in Args:"]
