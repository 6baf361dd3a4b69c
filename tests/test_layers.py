"""The package's architecture, checked from its source: no import circle among gnsx modules (imports inside
functions included), and dependencies that run one way between the layers.

Layers, lowest first (README, "Code structure"): ``core`` <- ``data``, ``mpm`` <- ``model`` <- ``rules`` <-
``evaluation`` <- ``training`` <- ``perf``, ``study``. ``rules`` (the simulator's hand-written rules) sits
above ``model``, so the model reads as the paper's and knows nothing of them: they reach its one rollout loop
through the loop's extension points (``gnsx.model.rollout``'s ``constraints`` and ``predict``). A module may
import its own layer and those below it. Entry points (``__main__`` modules) sit above every layer and nothing
inside gnsx imports them; yet an entry point lives in its layer's package, so each import of one across the
layers is named, with its reason, in ``CROSS_LAYER_ENTRY_POINTS``.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "gnsx"

#: Layer of each subpackage; a module may import modules of its own layer or a lower one.
LAYERS = {"core": 0, "data": 1, "mpm": 1, "model": 2, "rules": 3, "evaluation": 4, "training": 5, "perf": 6,
          "study": 6}  # fmt: skip
#: Pairs of layers that may not import each other although neither sits below the other.
SIBLINGS_APART = {("data", "mpm"): "data"}  # mpm writes the data format; data's CLI is an entry point
#: Each entry point that imports a layer its own layer may not import, as (entry point, layer): why. Every
#: other import of an entry point keeps to the layers like a library module's.
CROSS_LAYER_ENTRY_POINTS = {
    ("gnsx.data.__main__", "mpm"): (
        "the data CLI's `generate` runs the MPM solver: generating a dataset is a data task for the user, "
        "while the data layer's library modules never import the MPM"
    ),
}


def module_names() -> dict[str, Path]:
    """Every module of the package: dotted name -> file."""
    names = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names[".".join(parts)] = path
    return names


def imported_modules(name: str, path: Path, known: set[str]) -> set[str]:
    """The gnsx modules ``name`` imports anywhere in its source (module level, functions, type-checking
    blocks), each resolved to the longest known module name."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [f"{base}.{alias.name}" for alias in node.names] + [base]
        else:
            continue
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target.startswith("gnsx") and target != name:
                found.add(target)
    # ``from gnsx.x import y`` also names the package gnsx.x: keep it only when nothing under it was meant.
    return {t for t in found if not any(o.startswith(t + ".") for o in found)}


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    names = module_names()
    return {name: imported_modules(name, path, set(names)) for name, path in names.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of ``graph`` as a list of modules (first repeated at the end), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt) :] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def layer_of(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def is_entry_point(module: str) -> bool:
    return module.endswith(".__main__")


def against_the_layers(here: str, there: str) -> bool:
    """Whether a module of layer ``here`` importing one of layer ``there`` goes against the layers."""
    return LAYERS[there] > LAYERS[here] or (LAYERS[there] == LAYERS[here] and (here, there) in SIBLINGS_APART)


def test_the_cycle_finder_finds_a_circle_through_function_level_imports(tmp_path):
    """The checker itself: a circle closed by an import inside a function is found."""
    (tmp_path / "a.py").write_text("import gnsx.b\n")
    (tmp_path / "b.py").write_text("def f():\n    from gnsx.a import x\n")
    names = {"gnsx.a": tmp_path / "a.py", "gnsx.b": tmp_path / "b.py"}
    graph = {n: imported_modules(n, p, set(names)) for n, p in names.items()}
    assert find_cycle(graph) == ["gnsx.a", "gnsx.b", "gnsx.a"]
    assert find_cycle({"gnsx.a": {"gnsx.b"}, "gnsx.b": set()}) is None


def test_no_import_circle(graph):
    cycle = find_cycle(graph)
    assert cycle is None, "import circle: " + " -> ".join(cycle)


def test_every_module_belongs_to_a_layer(graph):
    """New code goes into a layer: gnsx/ holds only its layers and ``__init__.py``."""
    loose = [m for m in graph if m != "gnsx" and layer_of(m) is None]
    assert not loose, f"modules outside the layers {sorted(LAYERS)}: {loose}"


def test_dependencies_run_one_way(graph):
    wrong = []
    for module, imports in graph.items():
        if is_entry_point(module) or (here := layer_of(module)) is None:
            continue
        for target in imports:
            there = layer_of(target)
            if is_entry_point(target):
                wrong.append(f"{module} imports the entry point {target}")
            elif there is None or there == here:
                continue
            elif LAYERS[there] > LAYERS[here] or (
                LAYERS[there] == LAYERS[here] and (here, there) in SIBLINGS_APART
            ):
                wrong.append(f"{module} ({here}) imports {target} ({there})")
    assert not wrong, "imports against the layers:\n" + "\n".join(sorted(wrong))


def test_the_data_library_never_imports_the_mpm(graph):
    """Only the data CLI reaches the MPM (``CROSS_LAYER_ENTRY_POINTS``); the data layer's library does not."""
    wrong = [f"{module} imports {target}" for module, imports in graph.items()
             if layer_of(module) == "data" and not is_entry_point(module)
             for target in imports if layer_of(target) == "mpm"]  # fmt: skip
    assert not wrong, "the data layer's library imports the MPM:\n" + "\n".join(sorted(wrong))


def test_entry_points_cross_the_layers_only_where_listed(graph):
    """Every import of an entry point against the layers is listed with its reason, and every listed one is
    still made (a stale exception would hide a new one)."""
    crossing = {}
    for module, imports in graph.items():
        if not is_entry_point(module) or (here := layer_of(module)) is None:
            continue
        for target in imports:
            there = layer_of(target)
            if there is not None and there != here and against_the_layers(here, there):
                crossing.setdefault((module, there), []).append(target)
    unlisted = {key: sorted(found) for key, found in crossing.items() if key not in CROSS_LAYER_ENTRY_POINTS}
    assert not unlisted, f"entry points importing across the layers without a listed reason: {unlisted}"
    stale = set(CROSS_LAYER_ENTRY_POINTS) - set(crossing)
    assert not stale, f"listed in CROSS_LAYER_ENTRY_POINTS but no longer imported: {sorted(stale)}"


#: Run in a fresh interpreter: the third-party libraries are imported once, then each gnsx module is imported
#: in a forked child that has no gnsx module loaded, so no module leans on another having been imported first.
_IMPORT_EACH = """
import importlib, os, sys
import numpy, scipy, torch, lightning, omegaconf, hydra  # noqa: F401 (third-party, shared by the children)
failed = []
for name in sys.argv[1:]:
    pid = os.fork()
    if pid == 0:
        try:
            importlib.import_module(name)
        except BaseException as error:
            print(f"{name}: {type(error).__name__}: {error}", file=sys.stderr)
            os._exit(1)
        os._exit(0)
    _, status = os.waitpid(pid, 0)
    if status:
        failed.append(name)
sys.exit(1 if failed else 0)
"""


def test_every_module_imports_on_its_own():
    modules = sorted(n for n in module_names() if not n.endswith("__main__"))
    result = subprocess.run(
        [sys.executable, "-c", _IMPORT_EACH, *modules], capture_output=True, text=True, cwd=PACKAGE.parent
    )
    assert result.returncode == 0, result.stderr.strip()
