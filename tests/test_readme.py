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


def _build():
    import importlib.util

    if "docs_build" in sys.modules:
        return sys.modules["docs_build"]
    path = README.parent / "docs" / "build.py"
    spec = importlib.util.spec_from_file_location("docs_build", path)
    build = importlib.util.module_from_spec(spec)
    sys.modules["docs_build"] = build  # dataclasses resolve their module by name
    spec.loader.exec_module(build)
    return build


def _generated_names() -> list[str]:
    text = README.read_text(encoding="utf-8")
    return re.findall(r"<!-- generated:([\w-]+) -->", text)


def test_every_build_target_has_one_readme_block_and_back():
    names = _generated_names()
    assert len(names) == len(set(names)), f"a generated block appears twice: {names}"
    assert sorted(names) == sorted(_build().SECTIONS), (
        "README generated blocks and docs/build.py targets differ")


@pytest.mark.parametrize("name", _generated_names())
def test_generated_readme_block_matches_its_json(name):
    build = _build()
    text = README.read_text(encoding="utf-8")
    assert name not in build.stale_blocks(text), (
        f"README block {name!r} drifted from {build.SECTIONS[name].json}: run python docs/build.py")
    # the check is not vacuous: one changed character in this block is caught
    m = re.search(rf"<!-- generated:{name} -->\n(.*?)<!-- /generated:{name} -->", text, re.S)
    body = m.group(1)
    assert body.strip(), f"README block {name!r} is empty"
    edited = text.replace(m.group(0), m.group(0).replace(body, body + "| x |\n", 1), 1)
    assert build.stale_blocks(edited) == [name]


def test_generated_blocks_state_the_load_where_they_state_seconds():
    build = _build()
    for name in _generated_names():
        body = build.render(name)
        if re.search(r"\d ms\b|\d s\b|time s", body):
            assert "load" in body or "load" in build.SECTIONS[name].note, name
