"""The package's large-scale shape: dependencies run one way, and nothing imports in a circle.

The layers, lowest first (a module may import from its own layer and the layers below it):

0. foundation - conventions, units, statuses, particle models, optics, file I/O, the
   configuration-file schema;
1. ``scattering`` - the scattering theories that need no dipoles: Mie, coated sphere, sphere
   clusters, multipole expansions, T-matrices, the lens;
2. ``dda`` - the discrete dipole approximation (and ADDA), built on ``scattering``;
3. engines and configuration - the one list of engines, the choice among them, a particle's
   hologram with the engine chosen (``hologram``), and the config
   files that name them;
4. ``holomodel`` - the hologram model kit: parameters, forward model, least squares, results;
5. stage infrastructure - the tables and their schemas, the batch runner and the stage skeleton;
6. stages - crop, prefit, library, fit, analysis, simulate;
7. applications - run folders, demos, studies;
8. ``cli``, and the package's own ``__init__`` (the public API).

Every import counts, including those inside functions (a lazy import is still a dependency).
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "holofit"

LAYERS: tuple[frozenset[str], ...] = (
    frozenset({"conventions", "status", "cache", "progress", "provenance", "camera", "io",
               "config_schema", "optics", "particles"}),
    frozenset({"scattering"}),
    frozenset({"dda"}),
    frozenset({"engines", "config", "hologram"}),
    frozenset({"holomodel"}),
    frozenset({"tables", "batch"}),
    frozenset({"crop", "prefit", "library", "fit", "analysis", "simulate"}),
    frozenset({"runfolder", "demo", "studies"}),
    frozenset({"cli", "__init__"}),
)
LAYER_OF = {unit: i for i, layer in enumerate(LAYERS) for unit in layer}


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """The holofit modules ``name`` imports (``from holofit.x import y`` counts ``holofit.x.y``
    when that is a module, else ``holofit.x``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base
                       for a in node.names]
        else:
            continue
        found.update(t for t in targets if t == "holofit" or t.startswith("holofit."))
    found.discard(name)
    found.discard("holofit")  # the root only lends its __version__; its API is lazy
    return {t for t in found if t in known}


def _unit(module: str) -> str:
    """The layer unit of a module: its subpackage, or the top-level module's own name."""
    parts = module.split(".")
    return "__init__" if len(parts) == 1 else parts[1]


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    mods = _modules()
    known = set(mods)
    return {name: _imports(name, path, known) for name, path in mods.items()}


def test_every_unit_has_a_layer(graph: dict[str, set[str]]) -> None:
    missing = sorted({_unit(m) for m in graph} - set(LAYER_OF))
    assert not missing, f"put these in a layer of LAYERS: {missing}"


def test_dependencies_run_one_way(graph: dict[str, set[str]]) -> None:
    wrong = []
    for mod, deps in graph.items():
        if mod == "holofit":  # the lazy public API may name everything
            continue
        here = LAYER_OF.get(_unit(mod))
        for dep in deps:
            there = LAYER_OF.get(_unit(dep))
            if here is not None and there is not None and there > here:
                wrong.append(f"{mod} (layer {here}) imports {dep} (layer {there})")
    assert not wrong, "\n".join(sorted(wrong))


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one member (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_no_module_cycles(graph: dict[str, set[str]]) -> None:
    # a package's __init__ re-exporting its modules is not a cycle of the code's logic
    edges = {m: {d for d in deps if not (graph.get(d) is not None and d == m.rpartition(".")[0])}
             for m, deps in graph.items()}
    assert _cycles(edges) == []


def test_no_package_cycles(graph: dict[str, set[str]]) -> None:
    edges: dict[str, set[str]] = defaultdict(set)
    for mod, deps in graph.items():
        if mod == "holofit":
            continue
        for dep in deps:
            if _unit(dep) != _unit(mod) and dep != "holofit":
                edges[_unit(mod)].add(_unit(dep))
    assert _cycles(edges) == []


def test_cycle_finder_finds_a_cycle() -> None:
    # the checks above are only as good as the cycle finder
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []
