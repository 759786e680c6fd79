"""The package's import graph: no cycle, no import of another module's private name.

Walks every module of ``torchtof`` with :mod:`ast` (imports inside functions included, since
they run too) and builds the graph of imports between its modules.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "torchtof"

#: Private names imported across modules that other parts of the redesign still have to
#: remove: (importing module, imported module, name) -> reason. Each runs as an xfail;
#: delete the entry when the import is gone.
PENDING: dict[tuple[str, str, str], str] = {}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


MODULES = _modules()


def _resolve(mod: str, is_pkg: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(mod: str) -> list[tuple[str, str | None]]:
    """``(target module, imported name or None)`` of every import in ``mod``, in torchtof."""
    path = MODULES[mod]
    is_pkg = path.name == "__init__.py"
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, None) for a in node.names if a.name.startswith("torchtof")]
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(mod, is_pkg, node)
            if not target.startswith("torchtof"):
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.append((sub, None) if sub in MODULES else (target, a.name))
    return out


def _graph() -> dict[str, set[str]]:
    graph = {}
    for mod in MODULES:
        targets = set()
        for target, _ in _imports(mod):
            # importing a.b.c runs a and a.b first; an edge to the deepest module we know
            while target and target not in MODULES:
                target = target.rpartition(".")[0]
            if target and target != mod:
                targets.add(target)
        graph[mod] = targets
    return graph


def _is_ancestor(pkg: str, mod: str) -> bool:
    return mod.startswith(pkg + ".")


def test_walker_sees_the_package():
    assert {"torchtof", "torchtof.cli", "torchtof.report", "torchtof.recon"} <= set(MODULES)
    assert ("torchtof.report", "save_grid") in _imports("torchtof.cli") or any(
        t == "torchtof.report" for t, _ in _imports("torchtof.apps.demo"))


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Every back edge of a depth-first walk, as the cycle it closes."""
    color: dict[str, int] = {}
    stack: list[str] = []
    cycles = []

    def visit(m: str) -> None:
        color[m] = 1
        stack.append(m)
        for t in sorted(edges.get(m, ())):
            if color.get(t) == 1:
                cycles.append(stack[stack.index(t):] + [t])
            elif t not in color:
                visit(t)
        stack.pop()
        color[m] = 2

    for m in sorted(edges):
        if m not in color:
            visit(m)
    return cycles


def test_cycle_finder_finds_cycles():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == [["a", "b", "c", "a"]]
    assert _cycles({"a": {"b", "c"}, "b": {"c"}, "c": set()}) == []


def test_no_import_cycle():
    """No cycle between modules, except the ones a package's ``__init__`` makes by importing
    its own submodules (which import back from the package: Python allows that order)."""
    graph = _graph()
    edges = {m: {t for t in ts if not _is_ancestor(m, t) and not _is_ancestor(t, m)}
             for m, ts in graph.items()}
    cycles = _cycles(edges)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_library_does_not_import_the_tools():
    """The library proper never imports the CLI, the apps, the report helpers or the test
    oracles (the hardware subcommands, ``torchtof.hardware.cli``, are part of the CLI)."""
    tools = ("torchtof.cli", "torchtof.apps", "torchtof.report", "torchtof.testing",
             "torchtof.hardware.cli")
    bad = [(m, t) for m, ts in _graph().items() if not m.startswith(tools)
           for t in ts if t.startswith(tools)]
    assert not bad, bad


def _private_imports() -> list[tuple[str, str, str]]:
    """``(module, target, name)`` of every import of a private name (``_x``, not dunder), and
    of a private submodule from outside its package (``torchtof.recon._x`` is for
    ``torchtof.recon`` only; the top-level ``torchtof._x`` helpers serve the whole package)."""
    found = []
    for mod in MODULES:
        pkg = mod if MODULES[mod].name == "__init__.py" else mod.rpartition(".")[0]
        for target, name in _imports(mod):
            private_name = name is not None and name.startswith("_") and not name.startswith("__")
            parent, _, last = target.rpartition(".")
            private_mod = (last.startswith("_") and not last.startswith("__")
                           and parent != "torchtof")
            own = parent == pkg or _is_ancestor(parent, pkg)
            if private_name or (private_mod and not own):
                found.append((mod, target, name or ""))
    return found


def test_pending_entries_are_still_needed():
    """An entry of PENDING whose import is gone must be deleted (else it hides a relapse)."""
    stale = set(PENDING) - set(_private_imports())
    assert not stale, f"delete from PENDING: {sorted(stale)}"


def test_private_import_detector_works():
    src = "from .tval3 import _exact_solve\n"
    tree = ast.parse(src)
    node = tree.body[0]
    assert _resolve("torchtof.recon.depth", False, node) == "torchtof.recon.tval3"
    assert node.names[0].name.startswith("_")


@pytest.mark.parametrize("case", _private_imports() or [None],
                         ids=lambda c: "none" if c is None else f"{c[0]}<-{c[1]}.{c[2]}")
def test_no_private_name_imported_from_another_module(case, request):
    if case is None:
        return
    if case in PENDING:
        request.applymarker(pytest.mark.xfail(reason=PENDING[case]))
    raise AssertionError(f"{case[0]} imports the private {case[1]}.{case[2]}")


# -- the core install: `import torchtof` needs none of the extras ---------------------------
#: Modules of the extras (pyproject.toml): onnx, hardware, plot.
EXTRA_MODULES = ("onnx", "onnxruntime", "onnxscript", "usb", "zarr", "pygame", "tqdm",
                 "matplotlib")

_BLOCKED = """
import sys
BLOCK = {blocked!r}
class _Block:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCK:
            raise ImportError(f"{{name}} is blocked in this process")
sys.meta_path.insert(0, _Block())
{body}
"""


def _run_blocked(body: str, blocked=EXTRA_MODULES) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT.parent))
    code = _BLOCKED.format(blocked=tuple(blocked), body=body)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, timeout=120)


def test_blocker_blocks():
    res = _run_blocked("import onnx")
    assert res.returncode != 0 and "onnx is blocked" in res.stderr


def test_import_torchtof_with_core_dependencies_only():
    """``import torchtof`` (and the CLI parser, the adaptive and hardware packages, the
    progress bars) work with every extra blocked, no extra module gets imported, and each
    feature that needs an extra raises an ImportError naming it."""
    res = _run_blocked(
        "import torchtof, torchtof.recon, torchtof.adaptive, torchtof.hardware, torchtof.cli\n"
        "from torchtof._optional import progress_bar, require\n"
        "torchtof.cli.build_parser()\n"
        "bar = progress_bar(total=2)\n"
        "bar.update(2); bar.close()\n"
        "assert sum(progress_bar(range(3))) == 3\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in BLOCK))\n"
        "from torchtof.hardware.acquisition import require_zarr3\n"
        "for feature in (lambda: __import__('torchtof.onnx'), require_zarr3,\n"
        "                lambda: require('matplotlib', 'a figure')):\n"
        "    try:\n"
        "        feature()\n"
        "    except ImportError as exc:\n"
        "        print(exc)\n"
    )
    assert res.returncode == 0, res.stderr
    lines = res.stdout.strip().splitlines()
    assert lines[0] == "[]"
    assert len(lines) == 4
    for line, extra in zip(lines[1:], ("onnx", "hardware", "plot"), strict=True):
        assert f"pip install 'torchtof[{extra}]'" in line, line
