"""No function or method of the package is 100 lines or longer (issue 17: "the longest function
is under 100 lines"). A function's span runs from its ``def`` line to its last line (decorators
not counted; nested functions count inside their parent and on their own). No allowlist: split
a long function into named steps instead."""
import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "leaffit_usd"
MAX_LINES = 100  # a function spanning MAX_LINES lines or more fails


def function_spans(path: Path):
    """(qualified name, first line, number of lines) of every function and method in the file."""
    tree = ast.parse(path.read_text(), str(path))

    def walk(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    yield name, child.lineno, child.end_lineno - child.lineno + 1
                yield from walk(child, name + ".")
            else:
                yield from walk(child, prefix)

    yield from walk(tree, "")


def long_functions(root: Path = PKG, limit: int = MAX_LINES):
    out = []
    for path in sorted(root.rglob("*.py")):
        for name, line, n in function_spans(path):
            if n >= limit:
                out.append((n, f"{path.relative_to(root.parent)}:{line} {name} ({n} lines)"))
    return [s for _, s in sorted(out, reverse=True)]


def test_no_function_reaches_100_lines():
    long = long_functions()
    assert not long, (f"{len(long)} function(s) span {MAX_LINES} lines or more; split them into "
                      "named steps:\n  " + "\n  ".join(long))


def _function(name: str, n_lines: int, indent: str = "") -> str:
    """Source of a function spanning exactly ``n_lines`` lines."""
    return f"{indent}def {name}():\n" + f"{indent}    x = 0\n" * (n_lines - 2) + f"{indent}    return x\n"


def test_the_check_sees_long_functions(tmp_path):
    """The checker itself: 100-line functions, methods and nested functions fail, 99 lines pass."""
    inner = _function("inner", 100, "    ")
    (tmp_path / "m.py").write_text(
        _function("short", 99) + _function("long", 100)
        + "class C:\n" + _function("method", 130, "    ") + _function("fine", 99, "    ")
        + "def outer():\n" + inner + "    return inner\n")
    found = long_functions(tmp_path)
    assert [s.split()[1:] for s in found] == [
        ["C.method", "(130", "lines)"], ["outer", "(102", "lines)"],
        ["outer.inner", "(100", "lines)"], ["long", "(100", "lines)"]], found
