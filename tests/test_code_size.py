"""Module size and function complexity of the production code (issue 12), printed as a table.

Limits: the median module is at most ~150 lines; no module is over 600 lines unless it is one
algorithm (listed below with the reason); no function is over 120 lines or above a cyclomatic
complexity of 30 (McCabe, as flake8 counts it). Run ``pytest tests/test_code_size.py -s`` for the table.
"""
import ast
import statistics
from pathlib import Path

import mccabe

REPO = Path(__file__).resolve().parents[1]
PRODUCTION = ("core", "app", "widgets")
MEDIAN_MODULE_LINES = 150
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 120
MAX_COMPLEXITY = 30
#: Modules allowed above MAX_MODULE_LINES because they are one algorithm that reads best whole.
ONE_ALGORITHM = {
    "core/label/raster.py": "the z-buffered triangle rasteriser: set-up, candidate pixels, edge tests, depth keys",
}


def modules() -> list[Path]:
    return sorted(p for f in PRODUCTION for p in (REPO / f).rglob("*.py"))


def line_count(path: Path) -> int:
    return len(path.read_text().splitlines())


def functions(path: Path):
    """``(qualified name, lines, complexity)`` of every function and method of a module."""
    tree = ast.parse(path.read_text(), filename=str(path))
    visitor = mccabe.PathGraphingAstVisitor()
    visitor.preorder(tree, visitor)
    complexity = {}
    for graph in visitor.graphs.values():
        complexity[(graph.lineno, graph.entity.split(".")[-1])] = graph.complexity()
    out = []

    def walk(node, prefix=""):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{prefix}{child.name}"
                lines = child.end_lineno - child.lineno + 1
                cc = complexity.get((child.lineno, child.name), 1)
                out.append((name, lines, cc))
                walk(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                walk(child, f"{prefix}{child.name}.")
            else:
                walk(child, prefix)

    walk(tree)
    return out


def test_module_sizes_and_function_complexity():
    rows, problems = [], []
    sizes = []
    for path in modules():
        rel = str(path.relative_to(REPO))
        n = line_count(path)
        if path.name != "__init__.py" or n > 20:
            sizes.append(n)
        funcs = functions(path)
        longest = max(funcs, key=lambda f: f[1], default=("", 0, 0))
        worst = max(funcs, key=lambda f: f[2], default=("", 0, 0))
        rows.append((rel, n, longest, worst))
        if n > MAX_MODULE_LINES and rel not in ONE_ALGORITHM:
            problems.append(f"{rel}: {n} lines > {MAX_MODULE_LINES}")
        for name, lines, cc in funcs:
            if lines > MAX_FUNCTION_LINES:
                problems.append(f"{rel}: {name} is {lines} lines > {MAX_FUNCTION_LINES}")
            if cc > MAX_COMPLEXITY:
                problems.append(f"{rel}: {name} has complexity {cc} > {MAX_COMPLEXITY}")
    median = statistics.median(sizes)
    print(f"\n{'module':<44} {'lines':>6}  {'longest function':<40} {'lines':>5}  {'most complex':<40} {'CC':>3}")
    for rel, n, (ln, ll, _), (cn, _, cc) in sorted(rows, key=lambda r: -r[1]):
        print(f"{rel:<44} {n:>6}  {ln[:40]:<40} {ll:>5}  {cn[:40]:<40} {cc:>3}")
    print(f"{len(sizes)} modules, median {median:.0f} lines (limit {MEDIAN_MODULE_LINES})")
    if median > MEDIAN_MODULE_LINES:
        problems.append(f"median module {median:.0f} lines > {MEDIAN_MODULE_LINES}")
    assert not problems, "\n".join(problems)


def test_the_measure_counts_what_it_claims(tmp_path):
    """The complexity and length of a known function (guards the measuring code itself)."""
    src = tmp_path / "m.py"
    src.write_text("def f(a, b):\n    if a:\n        return 1\n    for x in b:\n        if x and a:\n"
                   "            return 2\n    return 3\n\n\nclass C:\n    def g(self):\n        return 0\n")
    funcs = {name: (lines, cc) for name, lines, cc in functions(src)}
    assert funcs["f"] == (7, 4)   # if, for, if -> 1 + 3 (mccabe does not count boolean operators)
    assert funcs["C.g"] == (2, 1)
