"""What ships cites only what ships: no pointer to the project's internal design and research
notes (its design and style documents, its research notes) or to its issue tracker ("issue 7", "the
issue's ..."). A reader of the package, tests, examples, benchmarks, export scripts, docs or
README has neither; a fact must name its published source (paper section or equation, an
article) or simply be stated."""

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCOPE = ("torchtof", "tests", "examples", "benchmarks", "export", "docs", "README.md")

#: Tests that must spell the forbidden names because they check for their absence.
EXEMPT = {"tests/test_readme.py", "tests/test_no_internal_refs.py"}

_I = re.IGNORECASE
#: The internal names, assembled so that this file does not spell them itself.
_DDOC, _SDOC, _NOTES = "DES" + "IGN", "STY" + "LE", "domain" + "[- _]notes"
#: (pattern, what it points at); the design document's name alone is matched in capitals
#: only, so the English word "design" stays free.
PATTERNS = [
    (re.compile(rf"\b(?:{_DDOC}|{_SDOC})\.md\b", _I), "internal design/style document"),
    (re.compile(rf"\b{_DDOC}\b"), "internal design document"),
    (re.compile(rf"\b{_NOTES}\b", _I), "internal research notes"),
    (re.compile(r"\bissues?\s*#?\s*\d+", _I), "issue-tracker number"),
    (re.compile(r"\bissue\s*#", _I), "issue-tracker number"),
    (re.compile(r"\b(?:the|this|that|stress)\s+issue(?:'s)?\b", _I), "issue-tracker pointer"),
]


def _files() -> list[Path]:
    """The files in scope: tracked and untracked-but-not-ignored ones when git is there,
    otherwise every file under the scope (no caches)."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "-co", "--exclude-standard", "--", *SCOPE],
            cwd=ROOT, capture_output=True, text=True, check=True, timeout=60,
        ).stdout
        names = [line for line in out.splitlines() if line]
        if names:
            return [ROOT / n for n in names if (ROOT / n).is_file()]
    except (OSError, subprocess.SubprocessError):
        pass
    files: list[Path] = []
    for entry in SCOPE:
        path = ROOT / entry
        if path.is_file():
            files.append(path)
        elif path.is_dir():
            files.extend(p for p in path.rglob("*")
                         if p.is_file() and "__pycache__" not in p.parts)
    return files


def _hits(text: str, rel: str) -> list[str]:
    hits = []
    for lineno, line in enumerate(text.splitlines(), 1):
        for pattern, what in PATTERNS:
            m = pattern.search(line)
            if m:
                hits.append(f"{rel}:{lineno}: {m.group(0)!r} ({what}): {line.strip()[:120]}")
                break
    return hits


def test_patterns_catch_internal_refs_and_spare_plain_words():
    d, st, no = _DDOC, _SDOC, "domain" + "-notes"
    bad = [f"see {d}.md §2", f"({d} §5)", f"{no} §5.1", f"{st}.md",
           "(issue 7)", "issue #12", "the issue's 1 %", "the stress issue"]
    good = ["GIDC design (Wang et al. 2022)", "the redesign", "DIP design.",
            "paper §3.1", "issued by the camera"]
    for s in bad:
        assert _hits(s, "x"), s
    for s in good:
        assert not _hits(s, "x"), s


def test_nothing_in_scope_cites_internal_notes_or_issues():
    files = _files()
    assert any(f.name == "README.md" for f in files)
    hits: list[str] = []
    for path in files:
        rel = path.relative_to(ROOT).as_posix()
        if rel in EXEMPT:
            continue
        data = path.read_bytes()
        if b"\0" in data[:8192]:
            continue  # binary (images)
        hits += _hits(data.decode("utf-8", errors="replace"), rel)
    assert not hits, "internal references in shipped files:\n" + "\n".join(hits)
