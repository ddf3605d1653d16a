"""The layering DESIGN.md promises, checked on the source (issue 40): every import of every module (inside
functions too), found with the AST, against one table of what each layer may import. A new import across a layer
fails here, with the module and the line.

The table is DESIGN.md's, amended where the code is right: ``formats/`` uses evtools' numba decoders
(``evtools._kernels``), the frame record (``evtools.frames``), the stop signal (``evtools.interrupt``) and the
version; it writes figures (matplotlib) and reads the RPG layout's images (OpenCV). ``evtools/render.py`` takes its
colour maps from matplotlib. The API layer (``evtools/api.py``, ``evtools/__init__.py``) is the one place in
``evtools/`` that reaches ``formats``."""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STDLIB = set(sys.stdlib_module_names) | {"__future__"}

ALLOWED = {
    "evtools": {"numpy", "cv2", "evtools"},
    "evtools/_kernels": {"numpy", "numba", "llvmlite", "evtools._kernels"},
    "formats": {"numpy", "h5py", "hdf5plugin", "aedat", "lz4", "zstandard", "cv2", "matplotlib", "evtools",
                "evtools.events", "evtools.errors", "evtools.frames", "evtools._kernels", "evtools.interrupt",
                "evtools.formats"},
    "cli": {"numpy", "click", "rich", "h5py", "cv2", "matplotlib", "dask", "evtools"},
}
"""Layer -> the modules it may import (a name allows its submodules); the standard library always."""
EXTRA = {
    "evtools/api.py": {"evtools.formats", "dv_processing"},  # the API layer: files, and the dv-processing bridge
    "evtools/__init__.py": {"evtools.formats"},
    "evtools/plots.py": {"matplotlib"},
    "evtools/render.py": {"matplotlib"},  # colour maps only
}
FORBIDDEN = {
    "evtools": ("evtools.formats", "evtools.cli"),  # the algorithms know nothing of files
    "evtools/_kernels": ("evtools.formats", "evtools.cli"),
    "formats": ("evtools.cli", "evtools.api"),
    "cli": (),
}
"""Layer -> the evtools modules it may never import (checked before what is allowed)."""


def _layer(relative: str) -> str:
    return "evtools/_kernels" if relative.startswith("evtools/_kernels/") else relative.split("/")[0]


def _imports(path: Path) -> list[tuple[int, str, tuple[str, ...]]]:
    """(line, module, names) of every absolute import in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name, ()) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module, tuple(alias.name for alias in node.names)))
    return found


def _covered(module: str, allowed: set[str]) -> bool:
    return any(module == name or module.startswith(name + ".") for name in allowed)


MODULES = sorted(str(path.relative_to(ROOT)) for folder in ("evtools", "formats", "cli")
                 for path in (ROOT / folder).rglob("*.py"))


def test_the_table_covers_every_module():
    assert len(MODULES) > 60 and {_layer(m) for m in MODULES} == set(ALLOWED)


@pytest.mark.parametrize("relative", MODULES)
def test_each_module_imports_only_what_its_layer_may(relative):
    layer = _layer(relative)
    allowed = ALLOWED[layer] | EXTRA.get(relative, set())
    wrong = []
    for line, module, names in _imports(ROOT / relative):
        if module.split(".")[0] in STDLIB:
            continue
        reached = [module] + [f"{module}.{name}" for name in names] if module == "evtools" else [module]
        for target in reached:  # `from evtools import formats` reaches evtools.formats
            if _covered(target, set(FORBIDDEN[layer]) - EXTRA.get(relative, set())):
                wrong.append(f"{relative}:{line} imports {target} (never in {layer}/)")
        if not _covered(module, allowed):
            wrong.append(f"{relative}:{line} imports {module} (not among {layer}/'s: {sorted(allowed)})")
    assert not wrong, "\n".join(wrong)


def test_numba_is_imported_only_by_the_kernels():
    users = sorted({relative for relative in MODULES for _, module, _ in _imports(ROOT / relative)
                    if module.split(".")[0] in ("numba", "llvmlite")})
    assert users and all(relative.startswith("evtools/_kernels/") for relative in users), users


def test_the_check_finds_a_crossing(tmp_path):
    """The check can fail: an algorithm module that imports a reader is reported with its line."""
    module = tmp_path / "bad.py"
    module.write_text("import numpy\n\ndef f():\n    from evtools.formats import open_events\n")
    assert [(line, name) for line, name, _ in _imports(module)] == [(1, "numpy"), (4, "evtools.formats")]
    assert _covered("evtools.formats", set(FORBIDDEN["evtools"]))
    assert _covered("evtools.formats.io", {"evtools.formats"}) and not _covered("evtools.formatsx", {"evtools.formats"})


def test_no_benchmark_diary_in_the_code():
    """Measurements that explain a choice live in docs/performance.md, not in docstrings and comments where no test
    keeps them true (issue 40): no 'before -> after' figure with a unit in the sources."""
    diary = re.compile(r"\d[\d.,]* ?(?:ms|s|Mev/s|MiB|ns|GB|MB)? ?-> ?\d[\d.,]* ?(?:ms|s|Mev/s|MiB|ns|GB|MB)\b")
    found = [f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
             for folder in ("evtools", "formats", "cli") for path in sorted((ROOT / folder).rglob("*.py"))
             for number, line in enumerate(path.read_text().splitlines(), 1) if diary.search(line)]
    assert not found, "\n".join(found)
    assert (ROOT / "docs" / "performance.md").exists()
