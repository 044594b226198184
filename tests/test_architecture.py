"""Architecture rules: imports inside the package (module level and inside functions,
string entry points loaded through :mod:`importlib` and the environments ``vesselid.envs``
included) form no cycle and point down the layers of the import-linter contract in
``pyproject.toml``; ``if TYPE_CHECKING:`` blocks do not count. The environments use only
public names of the rest of the package."""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import pytest

import vesselid
import vesselid.envs

ROOT = Path(vesselid.__file__).parent
ENVS = Path(vesselid.envs.__file__).parent  # installed as vesselid.envs (folder envs/)
REPO = Path(__file__).resolve().parents[1]  # the checkout: pyproject.toml


def _module_name(path: Path) -> str:
    if ENVS != ROOT / "envs" and path.is_relative_to(ENVS):
        parts = ("vesselid", "envs", *path.relative_to(ENVS).with_suffix("").parts)
    else:
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    paths = set(ROOT.rglob("*.py")) | set(ENVS.rglob("*.py"))
    return {_module_name(p): p for p in sorted(paths)}


def _imports() -> dict[str, set[str]]:
    """Module -> package modules it imports anywhere (except ``TYPE_CHECKING`` blocks)."""
    mods = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        deps: set[str] = set()
        for node in _nodes(ast.parse(path.read_text())):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module == "vesselid" and all(
                    a.name == "__version__" for a in node.names):
                continue  # a constant set before the package imports any module
            elif isinstance(node, ast.ImportFrom) and node.module:
                # ``from pkg import submodule`` depends on the submodule, not on pkg's names
                subs = [f"{node.module}.{a.name}" for a in node.names]
                targets = [t for t in subs if t in mods]
                if len(targets) < len(subs):
                    targets.append(node.module)
            deps |= {t for t in targets if t in mods and t != name}
        deps |= {t for t in _entry_points(path) if t in mods and t != name}
        graph[name] = deps
    return graph


#: A string naming a package module, alone or as an entry point ``"module:attribute"``.
_ENTRY = re.compile(r"^(vesselid(?:\.[a-z_][a-z0-9_]*)+)(?::[A-Za-z_][A-Za-z0-9_]*)?$")


def _entry_points(path: Path) -> set[str]:
    """Modules named by string constants (registries, lazy command tables, lazy attributes):
    :func:`importlib.import_module` turns them into imports that ``ast`` imports miss."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            m = _ENTRY.match(node.value)
            if m:
                found.add(m.group(1))
    return found


def _nodes(tree: ast.AST):
    """Every node, skipping the bodies of ``if TYPE_CHECKING:``."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING":
            todo.extend(node.orelse)
            continue
        todo.extend(ast.iter_child_nodes(node))


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph[n]):
            if state.get(m) == 1:
                return [*stack[stack.index(m):], m]
            if m not in state and (found := visit(m)):
                return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state and (found := visit(n)):
            return found
    return None


def test_no_import_cycle() -> None:
    graph = _imports()
    assert "vesselid.plant.catalogue" in graph and graph["vesselid.plant.systems"]
    assert "vesselid.envs.manoeuvring" in graph and graph["vesselid.envs.heave"]
    assert _cycle(graph) is None, " -> ".join(_cycle(graph) or [])


def test_cycle_detector_finds_a_cycle() -> None:
    assert _cycle({"a": {"b"}, "b": {"a"}}) == ["a", "b", "a"]


def _private_imports(module: str, path: Path) -> list[str]:
    """Names with a leading underscore (or from a private module) that ``module`` imports
    from outside its own package."""
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = []
    for node in _nodes(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            full = [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            full = [a.name for a in node.names]
        else:
            continue
        for name in full:
            parts = name.split(".")
            if parts[0] != "vesselid":
                continue
            for i, part in enumerate(parts[1:], 1):
                if part.startswith("_") and not part.startswith("__"):
                    owner = ".".join(parts[:i])  # the package or module the name is private to
                    owner_pkg = owner if owner in ("vesselid",) or (
                        (ROOT.parent / owner.replace(".", "/")).is_dir()) else owner.rsplit(
                        ".", 1)[0]
                    if package != owner_pkg and not package.startswith(owner_pkg + "."):
                        found.append(name)
                    break
    return found


def test_environments_use_public_names_only() -> None:
    """The environments step the plant through its public API (no private kernels)."""
    bad = {m: _private_imports(m, p) for m, p in _modules().items()
           if m.startswith("vesselid.envs")}
    assert "vesselid.envs.manoeuvring" in bad
    assert not any(bad.values()), {m: b for m, b in bad.items() if b}


def test_private_import_detector() -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "m.py"
        p.write_text("from vesselid.plant.vessels.kernel import _step\n"
                     "from vesselid.envs._x import y\n")
        assert _private_imports("vesselid.envs.m", p) == ["vesselid.plant.vessels.kernel._step"]


def _layers() -> list[list[str]]:
    """The layers contract of ``pyproject.toml``, top first, as full module prefixes."""
    import tomllib

    text = (REPO / "pyproject.toml").read_text()
    contracts = tomllib.loads(text)["tool"]["importlinter"]["contracts"]
    layers = next(c for c in contracts if c["type"] == "layers")
    (container,) = layers["containers"]
    return [[f"{container}.{part.strip().strip('()')}" for part in re.split(r"[|:]", layer)]
            for layer in layers["layers"]]


def _layer_of(module: str, layers: list[list[str]]) -> int | None:
    for rank, layer in enumerate(layers):
        if any(module == p or module.startswith(p + ".") for p in layer):
            return rank
    return None


def _upward(graph: dict[str, set[str]], layers: list[list[str]]) -> list[str]:
    """Imports from a lower layer into a higher one (rank 0 is the top)."""
    bad = []
    for importer, targets in graph.items():
        a = _layer_of(importer, layers)
        for target in targets:
            b = _layer_of(target, layers)
            if a is not None and b is not None and b < a:
                bad.append(f"{importer} -> {target}")
    return sorted(bad)


def test_imports_point_down_the_layers() -> None:
    """Every import, entry-point strings and function-level imports included, points down."""
    layers = _layers()
    assert layers[0] == ["vesselid.cli"] and layers[-1] == ["vesselid.core"]
    assert any("vesselid.envs" in layer for layer in layers)
    assert _upward(_imports(), layers) == []


def test_layer_check_finds_an_upward_import() -> None:
    layers = [["vesselid.cli"], ["vesselid.identify"], ["vesselid.model"]]
    graph = {"vesselid.model.spec": {"vesselid.identify.base"},
             "vesselid.identify.base": {"vesselid.model.spec"},
             "vesselid.cli.app": {"vesselid.identify.base"}}
    assert _upward(graph, layers) == ["vesselid.model.spec -> vesselid.identify.base"]


def test_nothing_outside_the_command_line_imports_it() -> None:
    graph = _imports()
    users = {m for m, deps in graph.items() for d in deps
             if d.startswith("vesselid.cli") and not m.startswith("vesselid.cli")}
    assert users <= {"vesselid.__main__"}, users


def test_import_linter_contracts_hold() -> None:
    """``lint-imports`` (the CI step) from the checkout."""
    pytest.importorskip("importlinter")
    import subprocess

    run = subprocess.run([sys.executable, "-c", "from importlinter.cli import lint_imports_command;"
                          " lint_imports_command()"], capture_output=True, text=True,
                         cwd=REPO)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
