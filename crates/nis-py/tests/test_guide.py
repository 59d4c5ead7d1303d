"""The Python examples of the docs run as written: every ```python block of docs/guide/*.md and
README.md, each in a fresh namespace and a temporary working directory. A block that cannot run
on its own is marked ```python-skip (and not collected). Also: every fenced block in the guide
names its language, since rustdoc runs unlabelled blocks as Rust."""

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[3]
DOCS = sorted((ROOT / "docs" / "guide").glob("*.md")) + [ROOT / "README.md"]
FENCE = re.compile(r"^```(.*)$")


def blocks(path):
    """(first line number, language, code) of every fenced block of the Markdown file."""
    found, lang, start, lines = [], None, 0, []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        m = FENCE.match(line)
        if m and lang is None:
            lang, start, lines = m.group(1).strip(), number + 1, []
        elif m and not m.group(1).strip():
            found.append((start, lang, "\n".join(lines) + "\n"))
            lang = None
        elif lang is not None:
            lines.append(line)
    assert lang is None, f"{path}: a block opened at line {start} is not closed"
    return found


EXAMPLES = [
    pytest.param(path, start, code, id=f"{path.name}:{start}")
    for path in DOCS
    for start, lang, code in blocks(path)
    if lang == "python"
]


def test_the_docs_have_python_examples():
    assert len(EXAMPLES) >= 5


@pytest.mark.parametrize("path,start,code", EXAMPLES)
def test_python_example_runs(path, start, code, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    # Line numbers in tracebacks point into the Markdown file.
    compiled = compile("\n" * (start - 1) + code, str(path), "exec")
    exec(compiled, {"__name__": "__guide__"})


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_every_fenced_block_names_its_language(path):
    unlabelled = [start - 1 for start, lang, _ in blocks(path) if not lang]
    assert not unlabelled, f"{path.name}: blocks without a language at lines {unlabelled}"

