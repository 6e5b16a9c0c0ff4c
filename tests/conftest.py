"""Shared test set-up.

The suite mirrors the package: `core/` (tcaff_gtsam), `mapping/` and `eval/`. Helper modules
that several folders use (`rgbd_scenes.py`) sit beside this file, whose folder pytest puts on
the import path. End-to-end tests that run whole studies, data sets or bags are marked `slow`:

    make test                      # everything (what CI runs)
    .venv/bin/pytest -m "not slow"  # the quick subset for development
"""

from __future__ import annotations

from pathlib import Path

import pytest

#: the repository's root folder
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def repo() -> Path:
    """The repository's root folder."""
    return REPO
