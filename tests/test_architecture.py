"""The layering of docs/architecture.md, checked by import-linter (contracts in pyproject.toml)."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_import_contracts_are_kept():
    exe = shutil.which("lint-imports") or str(Path(sys.executable).parent / "lint-imports")
    if not Path(exe).exists():
        pytest.fail("lint-imports is missing: install the test extra (pip install -e '.[test]')")
    proc = subprocess.run([exe, "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert re.search(r"Contracts: \d+ kept, 0 broken\.", proc.stdout), (
        proc.stdout
    )  # "10 broken" is not "0 broken"


def test_sim_and_drivers_import_without_the_application():
    code = "import sys, drivers, drivers.errors, sim, calibration; assert 'hlr_lab' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT, timeout=60)


def test_the_public_surface_is_declared_and_each_name_imports():
    import hlr_lab

    assert set(hlr_lab.__all__) == {"__version__", *hlr_lab._SURFACE}
    for name in hlr_lab.__all__:
        assert getattr(hlr_lab, name) is not None, name


def test_the_top_level_holds_only_the_public_surface_the_pipeline_errors_and_files():
    loose = sorted(p.name for p in (ROOT / "hlr_lab").glob("*.py"))
    assert loose == ["__init__.py", "errors.py", "files.py", "pipeline.py"]


def test_no_test_reaches_into_the_command_line_but_to_test_it():
    """Tests call the library; only these test the command line itself (and may import its modules)."""
    command_line_tests = {"test_cli.py"}
    for test in (ROOT / "tests").glob("test_*.py"):
        if test.name in command_line_tests:
            continue
        imports = re.findall(r"^\s*from (hlr_lab\.cli\.\w+) import", test.read_text(), flags=re.M)
        assert set(imports) <= {"hlr_lab.cli.main"}, f"{test.name} imports {imports}"
