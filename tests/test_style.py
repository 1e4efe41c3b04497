"""The repository is formatted and linted by ruff, and the package's annotations checked by
mypy, with the settings in ``pyproject.toml``.

Run ``ruff format . && ruff check --fix .`` from the repository root to fix what ruff reports,
and ``mypy`` there to see what mypy does.
"""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("command", [("format", "--check"), ("check",)], ids=["format", "check"])
def test_ruff(command):
    done = subprocess.run(
        [sys.executable, "-m", "ruff", *command, "."], cwd=ROOT, capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stdout + done.stderr


def mypy(root: Path, cache: Path, *paths: Path) -> subprocess.CompletedProcess:
    """``mypy`` run in ``root`` with its ``pyproject.toml``, the cache in ``cache``, on ``paths``
    (none: the files ``pyproject.toml`` names)."""
    return subprocess.run(
        [sys.executable, "-m", "mypy", "--cache-dir", str(cache), *map(str, paths)],
        cwd=root,
        capture_output=True,
        text=True,
        check=False,
    )


def test_mypy(tmp_path):
    done = mypy(ROOT, tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    # a user's script: the top-level entry points (imported lazily at run time) carry their
    # types, so a wrong argument is caught (checked against the cache just written: quick)
    script = tmp_path / "script.py"
    script.write_text("import iap_mjx\n\niap_mjx.train(42)\niap_mjx.evaluate_run('run', episodes='8')\n")
    done = mypy(ROOT, tmp_path, script)
    assert done.returncode == 1, done.stdout + done.stderr
    assert 'Argument 1 to "train" has incompatible type "int"' in done.stdout, done.stdout
    assert 'Argument "episodes" to "evaluate_run" has incompatible type "str"' in done.stdout, done.stdout


def test_mypy_sees_a_wrong_annotation(tmp_path):
    (tmp_path / "iap_mjx").mkdir()
    (tmp_path / "pyproject.toml").write_text((ROOT / "pyproject.toml").read_text())
    (tmp_path / "iap_mjx" / "__init__.py").write_text("def size(shape: tuple[int, int]) -> int:\n    return shape\n")
    done = mypy(tmp_path, tmp_path / "cache")
    assert done.returncode == 1 and "Incompatible return value type" in done.stdout, done.stdout + done.stderr


# The package's layers as iap_mjx/__init__.py lists them, lowest first; a module may import its
# own layer and those below, never one above.
LAYERS = {
    **dict.fromkeys(("configs", "chunks", "loops", "_mjx", "runtime"), 0),
    **dict.fromkeys(("attention", "render", "robots"), 1),
    "envs": 2,
    "policies": 3,
    "es": 4,
    "viz": 5,
    "paper": 6,
    "cli": 7,
}


def upward_imports(root: Path) -> set[tuple[str, str]]:
    """``(module path below root, layer imported)`` for every import of a higher layer."""
    import ast

    found = set()
    for path in root.rglob("*.py"):
        relative = path.relative_to(root)
        layer = relative.parts[0].removesuffix(".py")
        if layer not in LAYERS:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):  # import iap_mjx.es.train
                modules = [alias.name.split(".") for alias in node.names]
                names = [parts[1] for parts in modules if parts[0] == "iap_mjx" and len(parts) > 1]
            elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "iap_mjx":
                parts = node.module.split(".")
                names = [alias.name for alias in node.names] if len(parts) == 1 else [parts[1]]
            else:
                continue
            found |= {(relative.as_posix(), name) for name in names if LAYERS.get(name, -1) > LAYERS[layer]}
    return found


def test_a_lower_layer_never_imports_a_higher_one():
    assert upward_imports(ROOT / "iap_mjx") == set()


def test_the_layer_check_sees_an_upward_import(tmp_path):
    (tmp_path / "envs").mkdir()
    (tmp_path / "envs" / "bad.py").write_text("def f():\n    from iap_mjx.es import train\n")
    (tmp_path / "es.py").write_text("from iap_mjx import envs, viz\nimport iap_mjx.cli.commands\n")
    assert upward_imports(tmp_path) == {("envs/bad.py", "es"), ("es.py", "viz"), ("es.py", "cli")}
