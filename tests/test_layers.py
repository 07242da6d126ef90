"""The import rule (docs/architecture.md): no package imports a higher layer, and no module
uses another module's private (underscore) names. Read from the source, lazy imports included;
the layers are read from the table in docs/architecture.md, the one statement of them."""
import ast
import re
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "leaffit_usd"
ARCHITECTURE = PKG.parent / "docs" / "architecture.md"


def read_layers(text: str) -> list[set[str]]:
    """The layer table of docs/architecture.md (rows ``| N | `unit`, `unit` | job |``), lowest
    first: a unit is a subpackage or a top-level module of leaffit_usd."""
    rows = {}
    for line in text.splitlines():
        m = re.match(r"\|\s*(\d+)\s*\|([^|]*)\|", line)
        if m:
            rows[int(m.group(1))] = set(re.findall(r"`([A-Za-z_]+)`", m.group(2)))
    assert rows and sorted(rows) == list(range(len(rows))), "the layer table is missing or has gaps"
    return [rows[i] for i in range(len(rows))]


LAYERS = read_layers(ARCHITECTURE.read_text())
LAYER = {u: i for i, units in enumerate(LAYERS) for u in units}
PRIVATE_MODULE_FRIENDS = {"leaffit_usd.commands._args": ("leaffit_usd.cli",)}


def unit_of(module: str) -> str:
    """'leaffit_usd.usd.writer' -> 'usd'; 'leaffit_usd' -> 'leaffit_usd'."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "leaffit_usd"


def imports(path: Path):
    """(line, imported module, [imported names]) of every leaffit_usd import in the file."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 \
                and node.module.split(".")[0] == "leaffit_usd":
            yield node.lineno, node.module, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "leaffit_usd":
                    yield node.lineno, a.name, []


def sources():
    for path in sorted(PKG.rglob("*.py")):
        module = ".".join(path.relative_to(PKG.parent).with_suffix("").parts)
        yield path, module.removesuffix(".__init__")


def upward_imports(files):
    bad = []
    for path, module in files:
        src = unit_of(module)
        for line, target, names in imports(path):
            dst = unit_of(target)
            if dst == "leaffit_usd" and names:   # `from leaffit_usd import x`: x may be a unit
                dst = names[0] if names[0] in LAYER else dst
            if LAYER[dst] > LAYER[src]:
                bad.append(f"{path.parent.name}/{path.name}:{line} {src} imports {target} ({dst})")
    return bad


def private_imports(files):
    bad = []
    for path, module in files:
        for line, target, names in imports(path):
            package = module.rsplit(".", 1)[0]
            same_package = target == package or target.rsplit(".", 1)[0] == package
            private = [n for n in names if n.startswith("_") and n != "__version__"]
            # a private module may be used by its own package only (commands._args: the command
            # line's helpers, shared with cli.py, the command line's entry point)
            if any(p.startswith("_") and not p.startswith("__") for p in target.split(".")):
                owner = target.split("._")[0]
                users = (owner + ".",) + PRIVATE_MODULE_FRIENDS.get(target, ())
                if not module.startswith(users):
                    bad.append(f"{path.parent.name}/{path.name}:{line} uses private module {target}")
            if private and not same_package:
                bad.append(f"{path.parent.name}/{path.name}:{line} imports {private} from {target}")
    return bad


def test_every_unit_has_a_layer():
    units = {unit_of(m) for _, m in sources()}
    assert units <= set(LAYER), sorted(units - set(LAYER))


def test_no_package_imports_a_higher_layer():
    assert upward_imports(sources()) == []


def test_no_module_imports_another_modules_private_names():
    assert private_imports(sources()) == []


@pytest.mark.parametrize("line, kind", [("from leaffit_usd.pipeline import convert", "upward"),
                                        ("from leaffit_usd.mesh.template import _x", "private")])
def test_the_rule_catches_a_violation(tmp_path, line, kind):
    """A lower layer (usd) importing a higher one (pipeline), or a private name, is reported."""
    fake = tmp_path / "leaffit_usd" / "usd" / "fake.py"
    fake.parent.mkdir(parents=True)
    fake.write_text(f"def f():\n    {line}\n")
    found = (upward_imports if kind == "upward" else private_imports)([(fake, "leaffit_usd.usd.fake")])
    assert len(found) == 1, found


@pytest.mark.parametrize("line", ["import leaffit_usd", "from leaffit_usd import __version__"])
def test_importing_the_package_root_is_an_upward_import(tmp_path, line):
    """The root is an entry point on the top floor (it registers the schema and offers
    open_plant): a module inside the package that imports it (as usd/reader.py did, to register
    the schema) breaks the rule."""
    fake = tmp_path / "leaffit_usd" / "usd" / "fake.py"
    fake.parent.mkdir(parents=True)
    fake.write_text(line + "\n")
    assert len(upward_imports([(fake, "leaffit_usd.usd.fake")])) == 1


def test_the_layer_table_is_read_from_the_document():
    text = ARCHITECTURE.read_text()
    assert read_layers(text) == LAYERS and LAYER["leaffit_usd"] == LAYER["cli"] == len(LAYERS) - 1
    with pytest.raises(AssertionError):
        read_layers(text.replace("| 2 | `isolate`", "| 12 | `isolate`"))
