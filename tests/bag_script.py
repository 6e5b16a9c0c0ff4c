"""scripts/make_kimera_like_bag.py, loaded as a module for the tests."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "make_kimera_like_bag.py"


def load_bag_script():
    spec = importlib.util.spec_from_file_location("make_kimera_like_bag", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while building
    spec.loader.exec_module(module)
    return module
