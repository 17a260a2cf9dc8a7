"""The package's structure: dependencies that run one way between layers, no import cycles
between modules or between subpackages, every module importable on its own and in any order,
the public API of ``holofit/__init__`` resolvable, and the layout of the docs' architecture page
complete.

The layers, lowest first (a module may import from its own layer and the layers below it):

0. foundation - conventions, statuses and the quality rules, particle models, optics and the
   objective's aberration, file I/O, the configuration-file schema, the camera model,
   provenance, progress, the cache;
1. ``scattering`` - the scattering theories that need no dipoles: Mie, coated sphere, sphere
   clusters, multipole expansions, T-matrices, the lens;
2. ``dda`` - the discrete dipole approximation (and ADDA), built on ``scattering``;
3. engines and configuration - the one list of engines, the choice among them, a particle's
   hologram with the engine chosen (``hologram``), and the config files that name them;
4. ``holomodel`` - the hologram model kit: parameters, forward model, least squares, results;
5. stage infrastructure - the tables and their schemas, the batch runner and the stage skeleton;
6. stages - crop, prefit, calibrate, library, fit, analysis, simulate;
7. applications - run folders, demos, studies;
8. ``cli``, and the package's own ``__init__`` (the public API, lazy: it may name everything).

Every import counts, including those inside functions (a lazy import is still a dependency).
"""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

import holofit

PACKAGE = Path(holofit.__file__).resolve().parent


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """holofit modules that ``name`` imports anywhere in its body (lazy imports included)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            candidates = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join([*base, node.module] if node.module else base)
            else:
                module = node.module or ""
            candidates = [f"{module}.{a.name}" for a in node.names] + [module]
        else:
            continue
        for cand in candidates:
            while cand and cand not in known:
                cand = cand.rpartition(".")[0]
            if cand and cand not in (name, "holofit"):
                found.add(cand)
    return found


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (iterative Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    top = stack.pop()
                    on_stack.discard(top)
                    comp.append(top)
                    if top == node:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


LAYERS: tuple[frozenset[str], ...] = (
    frozenset({"conventions", "status", "quality", "cache", "progress", "provenance", "camera",
               "io", "config_schema", "optics", "aberration", "particles"}),
    frozenset({"scattering"}),
    frozenset({"dda"}),
    frozenset({"engines", "config", "hologram"}),
    frozenset({"holomodel"}),
    frozenset({"tables", "batch"}),
    frozenset({"crop", "prefit", "calibrate", "library", "fit", "analysis", "simulate"}),
    frozenset({"runfolder", "demo", "studies"}),
    frozenset({"cli"}),
)
LAYER_OF = {unit: i for i, layer in enumerate(LAYERS) for unit in layer}


def _unit(module: str) -> str:
    """The layer unit of a module: its subpackage, or the top-level module's own name."""
    parts = module.split(".")
    return "holofit" if len(parts) == 1 else parts[1]


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    mods = _modules()
    return {name: _imports(name, path, set(mods)) for name, path in mods.items()}


def test_every_subpackage_and_top_level_module_has_a_layer(graph: dict[str, set[str]]) -> None:
    missing = sorted({_unit(m) for m in graph} - set(LAYER_OF) - {"holofit"})
    assert not missing, f"put these in a layer of LAYERS: {missing}"


def test_dependencies_run_one_way(graph: dict[str, set[str]]) -> None:
    wrong = []
    for mod, deps in graph.items():
        if mod == "holofit":  # the lazy public API may name everything
            continue
        here = LAYER_OF[_unit(mod)]
        for dep in deps:
            there = LAYER_OF[_unit(dep)]
            if there > here:
                wrong.append(f"{mod} (layer {here}) imports {dep} (layer {there})")
    assert not wrong, "\n".join(sorted(wrong))


def test_no_import_cycles_between_subpackages(graph: dict[str, set[str]]) -> None:
    units: dict[str, set[str]] = {}
    for mod, deps in graph.items():
        if mod == "holofit":
            continue
        units.setdefault(_unit(mod), set()).update(
            _unit(d) for d in deps if _unit(d) not in (_unit(mod), "holofit"))
    for deps in list(units.values()):
        for d in deps:
            units.setdefault(d, set())
    assert _cycles(units) == []


def test_cycle_finder_finds_a_planted_cycle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert _cycles(graph) == [["a", "b", "c"]]


def test_no_import_cycles_inside_the_package() -> None:
    mods = _modules()
    graph = {name: _imports(name, path, set(mods)) for name, path in mods.items()}
    assert _cycles(graph) == []


@pytest.mark.parametrize("seed", [0, 1])
def test_every_module_imports_in_a_fresh_interpreter_in_any_order(seed: int) -> None:
    names = [n for n in _modules() if not n.endswith("__main__")]
    code = (
        "import importlib, json, random, sys\n"
        f"names = json.loads({json.dumps(json.dumps(names))})\n"
        f"random.Random({seed}).shuffle(names)\n"
        "for n in names:\n"
        "    importlib.import_module(n)\n"
        "print('imported', len(names))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert f"imported {len(names)}" in proc.stdout


def test_public_api_names_resolve() -> None:
    for name in holofit.__all__:
        assert getattr(holofit, name) is not None, name
    with pytest.raises(AttributeError):
        holofit.no_such_thing  # noqa: B018


def test_the_names_the_docs_promise_are_exported() -> None:
    """Every name of the package docstring's API table and every ``holofit.<name>(...)`` the
    README's and the docs' Python examples call is exported."""
    doc = holofit.__doc__ or ""
    table = doc[doc.index("The public API"):doc.index("Names are imported")]
    promised = set(re.findall(r"\b([A-Za-z_][A-Za-z0-9_]*)\b", table.split("::", 1)[1]))
    promised -= {"stages", "simulation", "configuration", "particles", "geometry", "engines",
                 "holograms", "fitting", "tables"}
    root = Path(__file__).resolve().parents[1]
    for page in [root / "README.md", *sorted((root / "docs").rglob("*.md"))]:
        promised |= set(re.findall(r"\bholofit\.([A-Za-z_][A-Za-z0-9_]*)\(", page.read_text()))
    missing = sorted(n for n in promised if n not in holofit.__all__)
    assert not missing, missing


def test_the_documented_layout_names_every_module() -> None:
    """The package tree of the docs' architecture page ("Repository layout") has a line for
    every module and subpackage of holofit, and none that does not exist."""
    root = Path(__file__).resolve().parents[1]
    readme = (root / "docs" / "architecture.md").read_text()
    section = readme[readme.index("## Repository layout"):]
    tree = section[section.index("```") + 3:]
    tree = tree[:tree.index("```")]
    listed: set[str] = set()
    stack: list[tuple[int, str]] = []  # (indent, folder)
    for line in tree.splitlines():
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        indent = len(line) - len(line.lstrip())
        name = stripped.split()[0]
        while stack and stack[-1][0] >= indent:
            stack.pop()
        path = "/".join([f for _, f in stack] + [name.rstrip("/")])
        if name.endswith("/"):
            stack.append((indent, name.rstrip("/")))
        if path.startswith("holofit"):
            listed.add(path)
    package = root / "holofit"
    # a subpackage's __init__ is its folder's line
    actual = {str(p.relative_to(root)) for p in package.rglob("*.py")
              if "__pycache__" not in p.parts
              and (p.name != "__init__.py" or p.parent == package)}
    actual |= {str(p.relative_to(root)) for p in package.rglob("*")
               if p.is_dir() and "__pycache__" not in p.parts and any(p.glob("*.py"))}
    actual.add("holofit")
    assert sorted(actual - listed) == [], "modules missing from docs/architecture.md's layout"
    extra = {p for p in listed - actual if not (root / p).is_file()}  # an __init__ may be named
    assert sorted(extra) == [], "docs/architecture.md lists modules that do not exist"


def test_the_api_reference_covers_every_subpackage_and_module() -> None:
    """Every subpackage and top-level module of holofit is rendered by a ``::: holofit.X``
    block of an API reference page (a subpackage's page shows its submodules)."""
    root = Path(__file__).resolve().parents[1]
    rendered: set[str] = set()
    for page in (root / "docs" / "api").glob("*.md"):
        rendered |= set(re.findall(r"^::: (holofit(?:\.[A-Za-z_][A-Za-z0-9_]*)*)\s*$",
                                   page.read_text(), flags=re.MULTILINE))
    package = root / "holofit"
    wanted = {f"holofit.{p.name}" for p in package.iterdir() if p.is_dir()
              and (p / "__init__.py").exists()}
    wanted |= {f"holofit.{p.stem}" for p in package.glob("*.py") if p.name != "__init__.py"}
    wanted.add("holofit")
    assert sorted(wanted - rendered) == [], "add these to a page of docs/api/"
