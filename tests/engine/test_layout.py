"""The package layout, checked by parsing the source (``ast``; nothing is imported).

Rules (issue 10):

* import directions inside the engine: kernels -> kernels (+ numpy/numba/math);
  core -> core; dic -> core, kernels; io -> core, dic; viz -> core, io;
  synthetic -> core, kernels; probes -> core, io, dic, viz; volume -> core, kernels, io;
  workflow -> any engine subpackage (each also its own);
* the engine never imports napari, Qt bindings, magicgui, vispy, superqt, the plugin
  modules (``napari_aldic._*``), the CLI or anything else outside ``napari_aldic.engine``;
* the CLI and the plugin modules use the engine's public API only:
  ``napari_aldic.engine``, ``.engine.io``, ``.engine.viz``, ``.engine.synthetic``,
  ``.engine.probes``;
* no module imports another module's ``_private`` name;
* no import cycles among the package's modules, counting every import that runs:
  module-level and inside functions (only ``if TYPE_CHECKING:`` imports are left out);
* no file over 600 lines (GUI files of the plugin: 400); no function over 80 lines
  (docstring not counted), numba kernels (``@njit``/``@jit``) up to 120.

Every check looks at every ``import`` statement (also those inside functions) unless
it says otherwise; relative imports are resolved to absolute module names.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

import napari_aldic

PKG = "napari_aldic"
ROOT = Path(napari_aldic.__file__).resolve().parent
ENGINE = f"{PKG}.engine"

#: engine subpackage -> the engine subpackages it may import (besides itself)
ENGINE_DEPS = {
    "kernels": set(),
    "core": set(),
    "dic": {"core", "kernels"},
    "io": {"core", "dic"},
    "viz": {"core", "io"},
    "synthetic": {"core", "kernels"},
    "probes": {"core", "io", "dic", "viz"},
    "workflow": {"core", "kernels", "dic", "io", "viz", "synthetic", "probes"},
    "sem": {"core", "kernels", "dic", "io", "viz"},
    # DVC (issue 28): its own 3-D kernels, the engine's types, io's volume readers
    "volume": {"core", "kernels", "io"},
}
#: the only outside packages the numba kernels may use
KERNEL_EXTERNAL = {"numpy", "numba", "math", "__future__"}
GUI_PACKAGES = {"napari", "qtpy", "PyQt5", "PyQt6", "PySide2", "PySide6", "magicgui", "vispy",
                "superqt"}
GUI_TOOLKITS = GUI_PACKAGES - {"napari", "vispy"}
#: what the CLI and the plugin modules may import from the engine
PUBLIC_ENGINE = {ENGINE, f"{ENGINE}.io", f"{ENGINE}.viz", f"{ENGINE}.synthetic",
                 f"{ENGINE}.probes", f"{ENGINE}.sem"}

MAX_FILE_LINES = 600
MAX_GUI_FILE_LINES = 400
MAX_FUNCTION_LINES = 80
MAX_KERNEL_LINES = 120


# ------------------------------------------------------------------ parsing
def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


@dataclass(frozen=True)
class Import:
    importer: str  # module that holds the statement
    target: str  # absolute module name imported (for ``from m import name``: m.name if
    #              that is a module of the package, else m)
    names: tuple[str, ...]  # names taken from the target ('' for ``import x``)
    line: int
    module_level: bool  # executed on import (not in a function, not TYPE_CHECKING-only)
    runs: bool = True  # executed at all (False: only under ``if TYPE_CHECKING:``)

    @property
    def where(self) -> str:
        return f"{self.importer}:{self.line}"


@dataclass
class Module:
    name: str
    path: Path
    tree: ast.Module
    is_package: bool

    @property
    def rel(self) -> str:
        return str(self.path.relative_to(ROOT.parent.parent if ROOT.parent.name == "src"
                                         else ROOT.parent))


def _load_modules() -> dict[str, Module]:
    mods = {}
    for path in sorted(ROOT.rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        name = _module_name(path)
        mods[name] = Module(name, path, ast.parse(path.read_text(encoding="utf-8"), str(path)),
                            path.name == "__init__.py")
    return mods


MODULES = _load_modules()


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _walk_imports(tree: ast.AST):
    """(node, executed, runs) for every Import/ImportFrom; executed: runs when the
    module is imported (not inside a function, not in an ``if TYPE_CHECKING:``
    block); runs: runs at all (not in an ``if TYPE_CHECKING:`` block)."""
    def visit(node, executed, runs):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node, executed, runs
            return
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            executed = False
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for stmt in node.body:
                yield from visit(stmt, False, False)
            for stmt in node.orelse:
                yield from visit(stmt, executed, runs)
            return
        for child in ast.iter_child_nodes(node):
            yield from visit(child, executed, runs)

    yield from visit(tree, True, True)


def _resolve_base(mod: Module, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    package = mod.name if mod.is_package else mod.name.rpartition(".")[0]
    parts = package.split(".")
    if node.level > 1:
        parts = parts[:len(parts) - (node.level - 1)]
    base = ".".join(parts)
    return f"{base}.{node.module}" if node.module else base


def _imports(mod: Module) -> list[Import]:
    out = []
    for node, module_level, runs in _walk_imports(mod.tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                out.append(Import(mod.name, alias.name, ("",), node.lineno, module_level,
                                  runs))
            continue
        base = _resolve_base(mod, node)
        plain = []
        for alias in node.names:
            sub = f"{base}.{alias.name}"
            if sub in MODULES:  # ``from package import submodule``
                out.append(Import(mod.name, sub, ("",), node.lineno, module_level, runs))
            else:
                plain.append(alias.name)
        if plain:
            out.append(Import(mod.name, base, tuple(plain), node.lineno, module_level, runs))
    return out


IMPORTS = {name: _imports(mod) for name, mod in MODULES.items()}


def _internal(target: str) -> str | None:
    """The package module an import refers to (longest existing prefix), or None."""
    if target != PKG and not target.startswith(PKG + "."):
        return None
    parts = target.split(".")
    while parts and ".".join(parts) not in MODULES:
        parts.pop()
    return ".".join(parts) if parts else None


def _top(target: str) -> str:
    return target.split(".")[0]


def _engine_part(module: str) -> str | None:
    """'core', 'dic', ... for modules inside an engine subpackage; '' for the engine's
    own top-level modules; None outside the engine."""
    if module == ENGINE:
        return ""
    if not module.startswith(ENGINE + "."):
        return None
    part = module.split(".")[2]
    return part if part in ENGINE_DEPS else ""


def _is_front_end(module: str) -> bool:
    """CLI and plugin modules: napari_aldic._*, napari_aldic.cli(.*)."""
    parts = module.split(".")
    return len(parts) >= 2 and (parts[1].startswith("_") or parts[1] == "cli")


def _report(problems: list[str], what: str) -> None:
    if problems:
        pytest.fail(f"{len(problems)} {what}:\n  " + "\n  ".join(problems), pytrace=False)


# ------------------------------------------------------------------ sanity
def test_the_parser_sees_the_package():
    assert f"{ENGINE}.core" in MODULES, f"no engine/core under {ROOT}"
    assert any(_is_front_end(m) for m in MODULES)
    # relative imports resolve to package modules
    resolved = [i for imps in IMPORTS.values() for i in imps if _internal(i.target)]
    assert len(resolved) > 50


# ------------------------------------------------------------------ import directions
def test_engine_import_directions():
    problems = []
    for name, imports in IMPORTS.items():
        part = _engine_part(name)
        if not part:  # outside the engine, or engine/__init__ (may import any subpackage)
            continue
        allowed = ENGINE_DEPS[part] | {part}
        for imp in imports:
            target = _internal(imp.target)
            if target is None:
                if part == "kernels" and _top(imp.target) not in KERNEL_EXTERNAL:
                    problems.append(f"{imp.where}: kernels import {imp.target} "
                                    f"(only {sorted(KERNEL_EXTERNAL)})")
                continue
            other = _engine_part(target)
            if other is None:
                continue  # outside the engine: test_engine_stays_napari_free
            if other == "":
                problems.append(f"{imp.where}: {part} imports {target} (the engine's top "
                                f"level; {part} may import {sorted(allowed)})")
            elif other not in allowed:
                problems.append(f"{imp.where}: {part} imports {target} ({part} may import "
                                f"{sorted(allowed)})")
    _report(problems, "engine imports against the direction rules")


def test_engine_stays_napari_free():
    problems = []
    for name, imports in IMPORTS.items():
        if _engine_part(name) is None:
            continue
        for imp in imports:
            if _top(imp.target) in GUI_PACKAGES:
                problems.append(f"{imp.where}: the engine imports {imp.target}")
            target = _internal(imp.target)
            if target is not None and _engine_part(target) is None:
                problems.append(f"{imp.where}: the engine imports {target} "
                                "(outside napari_aldic.engine)")
    _report(problems, "engine imports of GUI or non-engine modules")


def test_cli_and_plugin_use_the_public_engine_api():
    problems = []
    for name, imports in IMPORTS.items():
        if not _is_front_end(name):
            continue
        for imp in imports:
            target = _internal(imp.target)
            if target is None or _engine_part(target) is None:
                continue
            if target not in PUBLIC_ENGINE:
                problems.append(f"{imp.where}: imports {target} (public API: "
                                f"{', '.join(sorted(PUBLIC_ENGINE))})")
    _report(problems, "CLI/plugin imports of non-public engine modules")


def test_no_module_imports_another_modules_private_name():
    problems = []
    for imports in IMPORTS.values():
        for imp in imports:
            if _internal(imp.target) is None:
                continue
            private = [n for n in imp.names if n.startswith("_") and not n.startswith("__")]
            if private:
                problems.append(f"{imp.where}: from {imp.target} import {', '.join(private)}")
    _report(problems, "imports of another module's private names")


# ------------------------------------------------------------------ cycles
def _import_graph(function_level: bool = True) -> dict[str, set[str]]:
    """Imports among package modules that run: module-level ones and (by default)
    those inside functions, which hide a dependency as much as any (two modules
    that import each other, one of them lazily, are still one tangle). Importing
    ``a.b.c`` at module level also runs the ``__init__`` of ``a`` and ``a.b``: edges
    to them too, unless the importer lies inside that package (then it is already
    being imported)."""
    graph: dict[str, set[str]] = {name: set() for name in MODULES}
    for name, imports in IMPORTS.items():
        mine = {".".join(name.split(".")[:k]) for k in range(1, name.count(".") + 2)}
        for imp in imports:
            counted = imp.module_level or (function_level and imp.runs)
            target = _internal(imp.target) if counted else None
            if target is None:
                continue
            if target != name:
                graph[name].add(target)
            if not imp.module_level:
                continue  # at call time the packages above are imported already
            parts = target.split(".")
            for k in range(1, len(parts)):  # the packages above the target
                package = ".".join(parts[:k])
                if package not in mine:
                    graph[name].add(package)
    return graph


def _strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm (iterative); components of more than one module."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        comp.append(member)
                        if member == node:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def test_cycle_finder_finds_a_known_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert _strongly_connected(graph) == [["a", "b", "c"]]


def test_function_level_imports_count():
    """The import test sees imports inside functions (and leaves ``TYPE_CHECKING``
    ones out): a lazy import back into a module is a cycle too."""
    lazy = [i for imps in IMPORTS.values() for i in imps
            if not i.module_level and i.runs and _internal(i.target)]
    assert len(lazy) > 20  # the plugin imports napari-side modules lazily
    module_only, every = _import_graph(function_level=False), _import_graph()
    assert sum(map(len, every.values())) > sum(map(len, module_only.values()))
    i = lazy[0]
    assert _internal(i.target) in every[i.importer] or _internal(i.target) == i.importer


def test_no_import_cycles():
    graph = _import_graph()
    cycles = _strongly_connected(graph)
    problems = []
    for comp in cycles:
        members = set(comp)
        edges = [f"{a} -> {b}" for a in comp for b in sorted(graph[a]) if b in members]
        problems.append(f"cycle among {', '.join(comp)}: {'; '.join(edges)}")
    _report(problems, "import cycles")


# ------------------------------------------------------------------ sizes
def _is_gui_file(name: str) -> bool:
    """Plugin modules that build widgets (import a GUI toolkit, or are named so)."""
    if not _is_front_end(name) or name.split(".")[1] == "cli":
        return False
    if name.split(".")[1] in {"_qt", "_widget", "_widgets"}:  # widget packages
        return True
    if any(word in name.rsplit(".", 1)[-1] for word in ("widget", "panel")):
        return True
    return any(_top(i.target) in GUI_TOOLKITS for i in IMPORTS[name])


def test_file_sizes():
    problems = []
    for name, mod in MODULES.items():
        n = len(mod.path.read_text(encoding="utf-8").splitlines())
        limit = MAX_GUI_FILE_LINES if _is_gui_file(name) else MAX_FILE_LINES
        if n > limit:
            problems.append(f"{mod.rel}: {n} lines (limit {limit})")
    _report(problems, "files over the size limit")


def _is_numba_kernel(fn: ast.FunctionDef) -> bool:
    for dec in fn.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name in {"njit", "jit", "generated_jit", "vectorize", "guvectorize", "stencil"}:
            return True
    return False


def _function_lines(fn: ast.FunctionDef) -> int:
    """Lines from ``def`` to the end, without the docstring."""
    n = fn.end_lineno - fn.lineno + 1
    doc = fn.body[0] if fn.body else None
    if (isinstance(doc, ast.Expr) and isinstance(doc.value, ast.Constant)
            and isinstance(doc.value.value, str)):
        n -= doc.end_lineno - doc.lineno + 1
    return n


def test_function_sizes():
    problems = []
    for mod in MODULES.values():
        for fn in ast.walk(mod.tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            kernel = _is_numba_kernel(fn)
            limit = MAX_KERNEL_LINES if kernel else MAX_FUNCTION_LINES
            n = _function_lines(fn)
            if n > limit:
                kind = "numba kernel" if kernel else "function"
                problems.append(f"{mod.rel}:{fn.lineno} {kind} {fn.name}: {n} lines "
                                f"(limit {limit})")
    _report(problems, "functions over the size limit")


@pytest.mark.parametrize("source, expected", [
    ('def f():\n    """Doc\n    more."""\n    return 1\n', 2),
    ("@nb.njit(cache=True)\ndef k(a):\n    return a\n", 2),
])
def test_function_line_count(source, expected):
    fn = ast.parse(source).body[0]
    assert _function_lines(fn) == expected
    assert _is_numba_kernel(fn) == ("njit" in source)
