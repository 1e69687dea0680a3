"""The packages' manifests are true to their imports, and the layer contract covers
every package.

- Each package's ``package.xml`` declares (``exec_depend``) exactly the project's
  packages its modules import, wherever in a module the import is: a missing one
  breaks a colcon install, an extra one hides what a package really needs.
- ``.importlinter`` (checked by ``lint-imports`` in ``make test``) names every package
  of src/ as a root package and places each in one layer: a new package outside the
  contract would be unchecked.
"""

import ast
import configparser
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = sorted(p.parent.name for p in (REPO / "src").glob("pkm_*/package.xml"))


def imported_packages(package: str) -> set[str]:
    """The project's packages (pkm_*) that the modules of ``package`` import."""
    found = set()
    for path in (REPO / "src" / package / package).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            found.update(n.split(".")[0] for n in names if n.startswith("pkm_"))
    return found - {package}


def declared_packages(package: str) -> set[str]:
    root = ET.parse(REPO / "src" / package / "package.xml").getroot()
    assert root.findtext("name") == package
    return {e.text for e in root.iter("exec_depend") if e.text.startswith("pkm_")}


def test_the_project_has_its_packages():
    assert {"pkm_kinematics", "pkm_common", "pkm_controller", "pkm_recording", "pkm_runs"} <= set(PACKAGES), PACKAGES


@pytest.mark.parametrize("package", PACKAGES)
def test_package_xml_declares_what_the_package_imports(package):
    imported, declared = imported_packages(package), declared_packages(package)
    assert declared == imported, (f"{package}/package.xml: missing exec_depend {sorted(imported - declared)}, "
                                  f"declared but not imported {sorted(declared - imported)}")


def test_the_layer_contract_names_every_package_once():
    config = configparser.ConfigParser()
    config.read(REPO / ".importlinter")
    roots = config["importlinter"]["root_packages"].split()
    layers = [line.strip() for line in config["importlinter:contract:layers"]["layers"].splitlines() if line.strip()]
    placed = [name.strip() for layer in layers for name in layer.split("|")]
    assert sorted(roots) == PACKAGES, f"root_packages {sorted(roots)} != the packages of src/ {PACKAGES}"
    assert sorted(placed) == PACKAGES, f"the layers place {sorted(placed)}, the packages of src/ are {PACKAGES}"


def test_no_module_over_600_lines_without_its_reason():
    """A module of src/ over ~600 lines says at its top why it is one piece."""
    long = []
    for path in sorted((REPO / "src").glob("pkm_*/pkm_*/*.py")):
        text = path.read_text(encoding="utf-8")
        doc = ast.get_docstring(ast.parse(text)) or ""
        if text.count("\n") > 600 and "Why over 600 lines" not in doc:
            long.append(f"{path.relative_to(REPO)} ({text.count(chr(10))} lines)")
    assert not long, f"modules over 600 lines without a reason at their top: {long}"
