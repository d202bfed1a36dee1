"""One module file of another checkout, loaded beside this checkout's own: the A/B benchmarks
(``ab_cell_extractor.py``, ``ab_mapping.py``, ``ab_loop_closer.py``) compare a base and this
checkout call by call in one process. Imported as a sibling module (the running script's folder
is first on ``sys.path``), so it also works where a step runs with another checkout on
``PYTHONPATH``."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path


def load_module(path: Path, name: str):
    """The module at ``path`` under ``name``; a missing file ends the running benchmark with a
    message naming the file."""
    path = Path(path)
    if not path.is_file():
        raise SystemExit(f"{Path(sys.argv[0]).stem}: no {path} (--base must be a checkout)")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module     # dataclasses look their module up
    spec.loader.exec_module(module)
    return module
