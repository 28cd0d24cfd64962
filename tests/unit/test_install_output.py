"""CI's check of `make install`'s output (.ci/check_install_output.py): a new user's first screen shows no
warnings. CI runs it on a fresh install; here it is shown to flag what setuptools printed before the
project root was declared the import root (pyproject.toml: package-dir), and to let pip's notes about
this machine's index configuration through."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / ".ci" / "check_install_output.py"

# What `make install` printed with setuptools' import finder for flat layouts (pip 26, setuptools 84).
SETUPTOOLS_WARNING = """\
  /tmp/pip-build-env-quuwnqs2/overlay/lib/python3.11/site-packages/setuptools/command/editable_wheel.py:354: \
BuildBackendWarning: Editable installation.
  !!

          ********************************************************************************
          Please be careful with folders in your working directory with the same
          name as your package as they may take precedence during imports.
          ********************************************************************************

  !!
    with strategy, WheelFile(wheel_path, "w") as wheel_obj:
"""
MACHINE_PIP_CONFIG = (
    "WARNING: Location 'file:///opt/pypi-more/simple/annotated-types/' is ignored: "
    "it is neither a file nor a directory.\n"
    "WARNING: Location 'file:///opt/pypi/simple/asyncua/' is ignored: it is neither a file nor a directory.\n"
)
CLEAN = """\
python3 -m venv .venv
.venv/bin/pip install --quiet --upgrade pip
.venv/bin/pip install --quiet -e '.[test]'
touch .venv/.installed
"""


def checker() -> ModuleType:
    spec = importlib.util.spec_from_file_location("check_install_output", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_setuptools_warning_is_flagged() -> None:
    found = checker().warnings_in((CLEAN + MACHINE_PIP_CONFIG + SETUPTOOLS_WARNING).splitlines())
    assert any("BuildBackendWarning" in line for line in found)
    assert not any("Location 'file:///opt/" in line for line in found)


def test_pip_deprecations_and_other_warnings_are_flagged() -> None:
    lines = [
        "DEPRECATION: Legacy editable install of cnc-gateway (setup.py develop) is deprecated.",
        "WARNING: The script cnc-gateway is installed in '/x/bin' which is not on PATH.",
    ]
    assert checker().warnings_in(lines) == lines


def test_a_clean_install_with_this_machines_pip_notes_passes(tmp_path: Path) -> None:
    log = tmp_path / "install.log"
    log.write_text(CLEAN + MACHINE_PIP_CONFIG)
    done = subprocess.run(
        [sys.executable, str(SCRIPT), str(log)], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr


def test_a_warning_fails_the_check_and_is_shown(tmp_path: Path) -> None:
    log = tmp_path / "install.log"
    log.write_text(CLEAN + SETUPTOOLS_WARNING)
    done = subprocess.run(
        [sys.executable, str(SCRIPT), str(log)], capture_output=True, text=True, check=False
    )
    assert done.returncode == 1
    assert "BuildBackendWarning: Editable installation." in done.stderr


def test_the_editable_install_puts_the_project_root_on_the_path() -> None:
    """The layout that keeps setuptools quiet: a plain .pth with the project root (not its import finder)."""
    import gateway

    assert Path(gateway.__file__).resolve().parent == ROOT / "gateway"
    pth = [p for p in map(Path, sys.path) if p.is_dir() for p in p.glob("__editable__.cnc_gateway-*.pth")]
    assert pth, "no editable install of cnc-gateway on sys.path"
    assert pth[0].read_text().split() == [str(ROOT)]
