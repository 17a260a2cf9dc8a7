"""A griffe extension: holofit's numpydoc docstrings (written for Sphinx) rendered by mkdocstrings.

holofit's docstrings follow numpydoc, whose cross-references and asides are reStructuredText:
``:func:`~holofit.fit.frame.fit_frame```, ``:class:`FrameProblem```, ``#:`` comments that
document a constant, ``Example::`` before a literal block, and simple RST tables. mkdocstrings
renders Markdown. Rather than rewrite every docstring (they stay valid numpydoc for Sphinx and
for ``help()``), this extension translates them when the API reference is built:

- a role whose target resolves to a documented, public holofit object becomes an autorefs link
  (``[`fit_frame`][holofit.fit.frame.fit_frame]``); any other target (private, external,
  undocumented) becomes inline code, so that no link can dangle and ``mkdocs build --strict``
  stays clean;
- ``#:`` comment lines right above a module or class attribute become its docstring (as
  Sphinx's autodoc reads them), so constants are documented in the reference;
- a paragraph ending in ``::`` ends in ``:`` (the literal block after it is a Markdown code
  block already, being indented);
- simple RST tables (``====  ====`` rulers) become Markdown tables.
"""

from __future__ import annotations

import ast
import re
from typing import Any

import griffe

ROLE = re.compile(r":(?:py:)?(mod|class|func|meth|attr|data|obj|exc|const):`([^`]+)`")
RULER = re.compile(r"^( *)(=+)( +=+)+ *$")


class NumpydocCompat(griffe.Extension):
    """Translate Sphinx roles, ``#:`` comments, ``::`` and RST tables (module docstring)."""

    def __init__(self) -> None:
        super().__init__()
        self._pending: list[griffe.Object] = []

    # ``#:`` comments: read from the source while the attribute's AST node is at hand
    def on_attribute_instance(self, *, node: ast.AST | griffe.ObjectNode, attr: griffe.Attribute,
                              **kwargs: Any) -> None:
        if attr.docstring is not None or attr.lineno is None:
            return
        try:
            lines = attr.lines_collection[attr.filepath]  # type: ignore[index]
        except (KeyError, TypeError, griffe.BuiltinModuleError):
            return
        i = attr.lineno - 2  # the line above the assignment, 0-based
        found: list[str] = []
        while i >= 0 and lines[i].strip().startswith("#:"):
            found.append(lines[i].strip()[2:].strip())
            i -= 1
        if found:
            text = " ".join(reversed(found))
            attr.docstring = griffe.Docstring(text, lineno=i + 2, endlineno=attr.lineno - 1,
                                              parent=attr)

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        objects = list(_walk(pkg))
        by_name: dict[str, list[str]] = {}
        for obj in objects:
            if _linkable(obj):
                by_name.setdefault(obj.name, []).append(obj.path)
        unique = {name: paths[0] for name, paths in by_name.items() if len(paths) == 1}
        for obj in objects:
            if obj.docstring is not None:
                obj.docstring.value = translate(obj.docstring.value, obj, unique)


def _walk(obj: griffe.Object):
    yield obj
    for member in obj.members.values():
        if member.is_alias:
            continue
        yield from _walk(member)  # type: ignore[arg-type]


def translate(text: str, scope: griffe.Object, unique: dict[str, str] | None = None) -> str:
    """The Markdown form of one docstring (module docstring); ``unique``: the path of each
    name that only one documented public object has (a last resort for a bare name)."""
    text = _tables(text)
    text = ROLE.sub(lambda m: _role(m.group(2), scope, unique or {}), text)
    return re.sub(r"(\S)::(\n\s*\n)", r"\1:\2", text)


def _role(content: str, scope: griffe.Object, unique: dict[str, str]) -> str:
    content = content.strip()
    explicit = re.fullmatch(r"(.+?)\s*<(.+)>", content)
    if explicit:
        shown, target = explicit.group(1), explicit.group(2)
    else:
        target = content
        short = target.startswith("~")
        target = target.lstrip("~")
        shown = target.rsplit(".", 1)[-1] if short else target.lstrip(".")
    target = target.lstrip(".")
    path = _resolve(target, scope)
    if path is None and "." not in target.rstrip("()"):
        path = unique.get(target.rstrip("()"))
    code = f"`{shown}`"
    return f"[{code}][{path}]" if path else code


def _resolve(target: str, scope: griffe.Object) -> str | None:
    """The path of the documented public holofit object ``target`` names from ``scope``."""
    collection = scope.modules_collection
    candidates = [target]
    s: griffe.Object | None = scope
    while s is not None:
        candidates.append(f"{s.path}.{target}")
        s = s.parent
    for cand in candidates:
        top, _, rest = cand.partition(".")
        if top != "holofit":
            continue
        try:
            obj = collection[top]
            for part in rest.split(".") if rest else []:
                obj = obj.members[part]
            final = obj.final_target if obj.is_alias else obj
        except (KeyError, griffe.AliasResolutionError, griffe.CyclicAliasError):
            continue
        return final.path if _linkable(final) else None
    return None


def _linkable(obj: griffe.Object) -> bool:
    """A public holofit object the reference renders (so that a link to it resolves)."""
    path = obj.path
    public = all(not p.startswith("_") or p == "__init__" for p in path.split("."))
    return path.startswith("holofit") and public and (obj.is_module or obj.docstring is not None)


def _tables(text: str) -> str:
    lines = text.split("\n")
    out: list[str] = []
    i = 0
    while i < len(lines):
        m = RULER.match(lines[i])
        if not m:
            out.append(lines[i])
            i += 1
            continue
        indent = len(m.group(1))
        spans = [(a.start(), a.end()) for a in re.finditer(r"=+", lines[i])]
        rulers = [i]
        j = i + 1
        while j < len(lines) and len(rulers) < 3:
            if RULER.match(lines[j]):
                rulers.append(j)
            j += 1
        if len(rulers) < 3:
            out.append(lines[i])
            i += 1
            continue

        def cells(line: str, spans=spans) -> list[str]:
            got = []
            for k, (a, _) in enumerate(spans):
                b = spans[k + 1][0] if k + 1 < len(spans) else len(line)
                got.append(line[a:b].strip())
            return got

        header = [" ".join(c) for c in zip(*(cells(x) for x in lines[rulers[0] + 1:rulers[1]]))]
        rows: list[list[str]] = []
        for line in lines[rulers[1] + 1:rulers[2]]:
            if not line.strip():
                continue
            c = cells(line)
            if rows and not c[0]:
                rows[-1] = [f"{a} {b}".strip() for a, b in zip(rows[-1], c)]
            else:
                rows.append(c)
        pad = " " * indent
        out.append("")
        out.append(pad + "| " + " | ".join(header) + " |")
        out.append(pad + "|" + "|".join(" --- " for _ in header) + "|")
        out.extend(pad + "| " + " | ".join(r) + " |" for r in rows)
        out.append("")
        i = rulers[2] + 1
    return "\n".join(out)
