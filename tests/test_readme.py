"""The README is executable: every ```python block runs, in order, in one namespace (later
blocks may use names an earlier block defined, as a reader would), and names nothing that
does not ship."""

import re
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def _blocks() -> list[tuple[int, str]]:
    text = README.read_text(encoding="utf-8")
    return [(text[: m.start()].count("\n") + 1, m.group(1)) for m in BLOCK.finditer(text)]


def test_readme_has_python_snippets():
    assert len(_blocks()) >= 3


def test_every_readme_python_snippet_runs():
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    namespace: dict = {"__name__": "__readme__"}
    try:
        for line, code in _blocks():
            try:
                exec(compile(code, f"README.md:{line}", "exec"), namespace)
            except Exception as exc:  # noqa: BLE001 - report which block failed
                pytest.fail(f"README.md python block at line {line} failed: "
                            f"{type(exc).__name__}: {exc}")
    finally:
        torch.set_num_threads(threads)


@pytest.mark.parametrize("name", ["DES" + "IGN.md", "STY" + "LE.md", "domain" + "-notes"])
def test_readme_cites_nothing_that_does_not_ship(name):
    assert name not in README.read_text(encoding="utf-8")


def test_generated_readme_tables_match_their_json():
    import importlib.util

    path = README.parent / "docs" / "build.py"
    spec = importlib.util.spec_from_file_location("docs_build", path)
    build = importlib.util.module_from_spec(spec)
    sys.modules["docs_build"] = build  # dataclasses resolve their module by name
    spec.loader.exec_module(build)
    text = README.read_text(encoding="utf-8")
    assert "<!-- generated:" in text
    assert build.stale_blocks(text) == [], "README tables drifted: run python docs/build.py"
    # the check is not vacuous: a changed number is caught
    edited = text.replace("<!-- generated:demo -->\n", "<!-- generated:demo -->\n| x |\n", 1)
    assert build.stale_blocks(edited) == ["demo"]
