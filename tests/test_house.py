"""The house rules, checked with the test suite: the layers go one way (import-linter's contracts in
pyproject.toml), the code passes ruff, and no new private name is imported from another module."""

import ast
import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"

#: ``(importer, owner, name)`` of the private names still imported across modules. Each is a name another
#: module uses, so it belongs public in its owner. Do not add to it: make the name public in the module that owns it.
PRIVATE_IMPORTS_LEFT: set = set()


def _tool(script: str, module: str) -> list[str]:
    """The command that runs a tool: its script next to this interpreter or on the PATH; skip without it."""
    if importlib.util.find_spec(module) is None:
        pytest.skip(f"{script} is not installed (it is in the 'test' extra: pip install '.[test]')")
    found = shutil.which(script, path=os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")]))
    if found is None:
        pytest.skip(f"{script}: the {module} package is installed but its command is not on the PATH")
    return [found]


def _run(command: list[str]) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(SRC), os.environ.get("PYTHONPATH")])))
    return subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


def test_the_import_contracts_hold():
    """lint-imports: the layers (CLI above the application above the bank above the core), the core never
    importing upward, no library module importing the CLI, no import cycle (pyproject.toml, [tool.importlinter])."""
    done = _run(_tool("lint-imports", "importlinter") + ["--no-cache"])
    assert done.returncode == 0, f"lint-imports found broken contracts:\n{done.stdout}\n{done.stderr}"
    assert "0 broken" in done.stdout


def test_ruff_passes():
    """ruff check src tests benchmarks, with the configuration in pyproject.toml ([tool.ruff])."""
    done = _run(_tool("ruff", "ruff") + ["check", "--no-cache", "src", "tests", "benchmarks"])
    assert done.returncode == 0, f"ruff found problems:\n{done.stdout}\n{done.stderr}"


def _private_imports(src: Path = SRC) -> set[tuple[str, str, str]]:
    """``(importer, owner, name)`` for each ``from kalmix.x import _y`` (relative or absolute) under
    ``src/kalmix`` where ``_y`` is a name of another module (not a private submodule, not a dunder)."""
    found = set()
    for path in sorted((src / "kalmix").rglob("*.py")):
        parts = list(path.relative_to(src).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
            package = parts
        else:
            package = parts[:-1]
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = package[:len(package) - (node.level - 1)]
                owner = ".".join(base + ([node.module] if node.module else []))
            else:
                owner = node.module or ""
            if owner.split(".")[0] != "kalmix":
                continue
            for alias in node.names:
                name = alias.name
                if not name.startswith("_") or name.startswith("__"):
                    continue
                candidate = src.joinpath(*owner.split("."), name)
                if candidate.with_suffix(".py").exists() or candidate.is_dir():   # a private submodule
                    continue
                found.add((".".join(parts), owner, name))
    return found


def test_no_new_private_name_is_imported_from_another_module():
    """A name other modules use is public in the module that owns it; only the known few are left."""
    new = sorted(_private_imports() - PRIVATE_IMPORTS_LEFT)
    assert not new, ("private names imported from another module (make them public in the module that owns "
                     f"them): {new}")


def test_the_private_import_scan_finds_relative_and_absolute_imports(tmp_path):
    package = tmp_path / "kalmix"
    (package / "core").mkdir(parents=True)
    (package / "__init__.py").write_text("from .core import _private_module, engine\n")
    (package / "core" / "__init__.py").write_text("")
    (package / "core" / "_private_module.py").write_text("")
    (package / "core" / "engine.py").write_text("from ..streaming import _leaves, tree_map\nfrom . import __doc__\n")
    (package / "streaming.py").write_text("from kalmix.core.engine import _check\nimport numpy\n")
    assert _private_imports(tmp_path) == {("kalmix.core.engine", "kalmix.streaming", "_leaves"),
                                          ("kalmix.streaming", "kalmix.core.engine", "_check")}


def test_property_tests_draw_the_same_examples_on_every_run():
    """tests/conftest.py loads a Hypothesis profile for the whole suite: derandomized (a failure in CI is one
    anyone can rerun), no deadline (a kernel compiles on its first example), the reproducing blob printed."""
    from hypothesis import settings

    if os.environ.get("HYPOTHESIS_PROFILE", "ci") != "ci":
        pytest.skip(f"another Hypothesis profile is loaded: {os.environ['HYPOTHESIS_PROFILE']}")
    assert settings.default.derandomize and settings.default.deadline is None and settings.default.print_blob
