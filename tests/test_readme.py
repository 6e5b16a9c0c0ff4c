"""The README's library example runs as pasted and finds the alignment it makes; its links
point at files that exist."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def test_the_library_example_runs_and_finds_the_truth(capsys):
    text = (REPO / "README.md").read_text()
    example = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    scope: dict = {}
    exec(compile(example, "README.md", "exec"), scope)
    np.testing.assert_allclose(scope["est"].x, [2.0, -1.0, 0.3], atol=0.05)
    assert capsys.readouterr().out.strip()


def test_the_readme_and_docs_links_point_at_files():
    pages = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
    for page in pages:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text()):
            if "://" in target:
                continue
            assert (page.parent / target).exists(), (page.name, target)
