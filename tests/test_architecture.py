"""Architecture rules: imports inside the package (module level and inside functions,
the environments ``vesselid.envs`` included) form no cycle; ``if TYPE_CHECKING:`` blocks do
not count. The environments use only public names of the rest of the package."""

from __future__ import annotations

import ast
from pathlib import Path

import vesselid
import vesselid.envs

ROOT = Path(vesselid.__file__).parent
ENVS = Path(vesselid.envs.__file__).parent  # installed as vesselid.envs (folder envs/)


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
        graph[name] = deps
    return graph


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
        p.write_text("from vesselid.plant.vessels.kernel import _step\nfrom vesselid.envs._x import y\n")
        assert _private_imports("vesselid.envs.m", p) == ["vesselid.plant.vessels.kernel._step"]
