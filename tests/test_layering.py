"""Layering: the library never imports the command line, and no module imports itself back (no import cycles)."""

import subprocess
import sys


def test_the_library_does_not_import_the_cli():
    code = (
        "import importlib, pkgutil, sys\n"
        "def walk(package):\n"
        "    for m in pkgutil.iter_modules(package.__path__, package.__name__ + '.'):\n"
        "        if m.name in ('hybridfit.cli', 'hybridfit.__main__'):\n"
        "            continue\n"
        "        module = importlib.import_module(m.name)\n"
        "        if m.ispkg:\n"
        "            walk(module)\n"
        "import hybridfit\n"
        "walk(hybridfit)\n"
        "print(sorted(n for n in sys.modules if n.startswith('hybridfit.cli')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out


def _imports(path, module: str, is_package: bool, modules: set[str]) -> set[str]:
    """The hybridfit modules that a module imports, at top level or inside functions."""
    import ast

    base = module.split(".") if is_package else module.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                target = ".".join(base[: len(base) - node.level + 1] + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                found.add(f"{target}.{alias.name}" if f"{target}.{alias.name}" in modules else target)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return found & modules


def import_graph(root) -> dict[str, set[str]]:
    """{module: the modules it imports} over the modules (not packages) under ``root``/hybridfit."""
    files = {}
    for path in (root / "hybridfit").rglob("*.py"):
        parts = list(path.relative_to(root).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        files[".".join(parts[:-1] if is_package else parts)] = (path, is_package)
    modules = set(files)
    return {name: {m for m in _imports(path, name, pkg, modules) if m != name and not files[m][1]}
            for name, (path, pkg) in files.items() if not pkg}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The groups of modules that import each other, directly or through others."""
    def reach(start):
        seen, todo = set(), [start]
        while todo:
            for nxt in graph.get(todo.pop(), ()):
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        return seen

    reachable = {m: reach(m) for m in graph}
    groups = {frozenset({m} | {n for n in reachable[m] if m in reachable[n]}) for m in graph if m in reachable[m]}
    return sorted(sorted(g) for g in groups)


def test_no_module_imports_itself_back():
    from pathlib import Path

    assert cycles(import_graph(Path(__file__).resolve().parents[1])) == []


def test_the_cycle_check_finds_a_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(graph) == [["a", "b", "c"]]


def test_the_package_layers_import_one_way():
    """No cycle between hybridfit's top-level parts (model/, objective, problem, optimizer,
    fitting/, forest/, synthetic/, datasets/, study/, ...): each imports only lower ones."""
    from pathlib import Path

    graph = import_graph(Path(__file__).resolve().parents[1])
    part = lambda module: module.split(".")[1]  # noqa: E731
    parts: dict[str, set[str]] = {}
    for module, imported in graph.items():
        parts.setdefault(part(module), set()).update(part(m) for m in imported if part(m) != part(module))
    assert cycles(parts) == []
