"""Every place the help texts, the error messages and the docs point a reader to exists: the
file, and the section when one is named (`docs/sweeps.md#running-on-a-real-cluster`). And the
command list of `tcaff --help` shows each command's summary whole, as one sentence, and no
on/off flag is shown as if it took a value."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from tcaff_gtsam.eval.cli import app
from typer.main import get_command
from typer.testing import CliRunner

REPO = Path(__file__).resolve().parents[1]
SOURCES = [path for folder in ("tcaff_gtsam", "eval", "node", "mapping")
           for path in sorted((REPO / folder).rglob("*.py"))]
#: a pointer into the project's documents: a file, and optionally a section of it
POINTER = re.compile(r"\b((?:docs/)?[\w-]+\.md)(?:#([\w-]+))?")
#: a section named in words ("the README's cluster section"), which a reader cannot follow
VAGUE = re.compile(r"README(?:'s [\w ]+ section|\))")


def slug(heading: str) -> str:
    """The anchor a Markdown renderer gives a heading: lower case, punctuation dropped,
    spaces as hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)  # no headings in code
    return {slug(m) for m in re.findall(r"^#{1,6} (.+)$", text, re.M)}


def broken(text: str, base: Path) -> list[str]:
    """The pointers in `text` whose file (relative to the repository or to `base`) or section
    does not exist, and the vague ones."""
    out = [m.group(0) for m in VAGUE.finditer(text)]
    for m in POINTER.finditer(text):
        name, section = m.groups()
        candidates = [REPO / name, base / name, REPO / "docs" / name]
        page = next((c for c in candidates if c.is_file()), None)
        if page is None:
            if name.startswith("docs/") or section:
                out.append(m.group(0))
            continue  # a file name that is not a pointer (results.md, a user's notes.md)
        if section and section not in anchors(page):
            out.append(m.group(0))
    return out


def test_slug_follows_the_renderer():
    assert slug("Running on a real cluster") == "running-on-a-real-cluster"
    assert slug("The span of the maps") == "the-span-of-the-maps"
    assert slug("TCAFF: `scripts/bench_tcaff.py`") == "tcaff-scriptsbench_tcaffpy"


def test_a_missing_section_or_a_section_in_words_is_caught():
    assert broken("see docs/sweeps.md#running-on-a-real-cluster", REPO) == []
    assert broken("see docs/sweeps.md#clusters", REPO) == ["docs/sweeps.md#clusters"]
    assert broken("see docs/nowhere.md", REPO) == ["docs/nowhere.md"]
    assert broken("(see the README's cluster section)", REPO) == ["README's cluster section"]
    assert broken("need tcaff-gtsam installed (see the README).", REPO) == ["README)"]


@pytest.mark.parametrize("command", [None, *sorted(get_command(app).commands)])
def test_help_texts_point_at_places_that_exist(command):
    args = ["--help"] if command is None else [command, "--help"]
    result = CliRunner().invoke(app, args, env={"COLUMNS": "400"})
    assert result.exit_code == 0, result.output
    text = re.sub(r"[│╭╮╰╯─]", " ", result.output)
    assert broken(" ".join(text.split()), REPO) == []
    # an on/off flag takes no value: no type beside it (typer 0.29 draws `<bool>`)
    assert "<bool>" not in text


@pytest.mark.parametrize("source", SOURCES, ids=lambda p: str(p.relative_to(REPO)))
def test_messages_and_docstrings_point_at_places_that_exist(source):
    assert broken(source.read_text(), source.parent) == []


def test_links_between_documents_name_sections_that_exist():
    for page in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        for target, section in re.findall(r"\]\(([^)#\s]*)#([^)\s]+)\)", page.read_text()):
            if "://" in target:
                continue
            linked = page if not target else page.parent / target
            assert section in anchors(linked), (page.name, target, section)


@pytest.mark.parametrize("name", sorted(get_command(app).commands))
def test_each_command_summary_is_one_line(name):
    """The command list shows a summary's line breaks as they are: a first paragraph written
    over several lines breaks mid-sentence there."""
    summary = get_command(app).commands[name].help.strip().split("\n\n")[0]
    assert "\n" not in summary and len(summary) <= 110, summary


def test_the_docs_examples_import_what_exists():
    """Each `from tcaff_gtsam... import name` of the README's and the docs' Python examples
    names a module and a name that exist (an example imported a class renamed long before)."""
    import ast
    import importlib.util

    missing = []
    for page in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        for block in re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.S):
            for node in ast.walk(ast.parse(block)):
                if not (isinstance(node, ast.ImportFrom) and node.module
                        and node.module.split(".")[0] == "tcaff_gtsam"):
                    continue
                module = importlib.import_module(node.module)
                missing += [f"{page.name}: from {node.module} import {alias.name}"
                            for alias in node.names if not hasattr(module, alias.name)
                            and importlib.util.find_spec(f"{node.module}.{alias.name}") is None]
    assert not missing, missing


@pytest.mark.parametrize("name", sorted(get_command(app).commands))
def test_help_texts_show_their_brackets(name):
    """The help is drawn as rich markup, which takes `[viz]` for a style and drops it
    ("pip install 'tcaff-gtsam'"): a bracket the reader should see is escaped, `\\[viz]`."""
    command = get_command(app).commands[name]
    for text in [command.help or "", *(getattr(p, "help", None) or "" for p in command.params)]:
        assert not re.findall(r"(?<!\\)\[[a-z/][^\]\n]*\]", text), text
