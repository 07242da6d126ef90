"""pyproject's runtime dependencies are exactly the third-party packages leaffit_usd imports
(optional ones behind an extra other than [dev])."""
import ast
import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IMPORT_NAME = {"usd-core": "pxr", "OpenImageIO": "OpenImageIO"}   # distribution -> module
PROVIDED_BY = {"werkzeug": "flask"}                                  # flask's own dependency


def _names(reqs):
    return {IMPORT_NAME.get(n, n.replace("-", "_")) for n in (re.split(r"[<>=!~ \[]", r)[0] for r in reqs)}


def third_party_imports() -> set[str]:
    found = set()
    for path in (ROOT / "leaffit_usd").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                mods = [node.module]
            else:
                continue
            for m in mods:
                top = m.split(".")[0]
                if top not in sys.stdlib_module_names and top not in ("leaffit_usd", "__future__"):
                    found.add(PROVIDED_BY.get(top, top))
    return found


def test_dependencies_are_what_the_package_imports():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    required = _names(project["dependencies"])
    extras = project["optional-dependencies"]
    optional = set().union(*(_names(v) for k, v in extras.items() if k != "dev"))
    imported = third_party_imports()
    assert imported - required - optional == set(), "imported but not declared"
    assert required - imported == set(), "declared but not imported"
    assert optional <= imported
