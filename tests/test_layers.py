"""The package's layers (pyproject.toml, [tool.importlinter]): a module imports only from its own
layer and the layers below it; plotting and show import no study. Checked by import-linter on the
package as it is, and on a copy with one plotting module made to import a study, which must fail."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytest.importorskip("importlinter", reason="import-linter is in the [test] extra")


def lint_imports(root: Path) -> subprocess.CompletedProcess:
    """``lint-imports`` on the package under ``root`` with the contract of ``root/pyproject.toml``."""
    code = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
    return subprocess.run([sys.executable, "-c", code, "--no-cache"], cwd=root, capture_output=True, text=True,
                          timeout=300, env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"})


def test_the_package_keeps_its_layers():
    done = lint_imports(ROOT)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "1 kept, 0 broken" in done.stdout


@pytest.mark.parametrize("module, line", [
    ("plotting/study.py", "from ..studies import paper  # noqa"),
    ("show.py", "from .studies import occlusion  # noqa"),
    ("simulation.py", "from . import runner  # noqa"),
])
def test_a_module_importing_a_layer_above_breaks_the_contract(tmp_path, module, line):
    """The mutation the contract is there for: the same check on a copy of the package with one
    upward import added fails and names it."""
    shutil.copytree(ROOT / "gimbal_lab", tmp_path / "gimbal_lab", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    path = tmp_path / "gimbal_lab" / module
    path.write_text(path.read_text() + "\n" + line + "\n")
    done = lint_imports(tmp_path)
    assert done.returncode != 0 and "0 kept, 1 broken" in done.stdout, done.stdout + done.stderr
    importer = "gimbal_lab." + module.removesuffix(".py").replace("/", ".")
    assert importer in done.stdout
