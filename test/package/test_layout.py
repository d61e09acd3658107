"""The rooms say what they hold (doc/architecture.md, "Layers"): the ROS shell and the tools in
modules of at most MAX_MODULE_LINES, functions of at most MAX_FUNCTION_LINES (their docstrings
left out) everywhere but the documented exceptions, and each tool (a command of setup.py's
EXECUTABLES in motion_ctrl.tools) importing no other tool: what tools share lives in
procedures/, bags/, analysis/, plotting/."""
import ast
import pathlib

from conftest import REPO_ROOT, setup_table

PACKAGE = pathlib.Path(REPO_ROOT) / 'motion_ctrl'
MAX_MODULE_LINES = 400
MAX_FUNCTION_LINES = 60
# Longer on purpose, each for its reason (doc/architecture.md, "Where the core is larger ...").
EXCEPTIONS = {
    # the plant's integration kernel, compiled: one loop over locals that mypyc keeps as C
    # doubles; split into calls it would box and unbox every substep (test_plant_kernel)
    'sim/plant.py:_substeps',
}


def _sources():
    return sorted(PACKAGE.rglob('*.py'))


def _functions(tree):
    return [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]


def _length(f) -> int:
    """A function's lines from `def` to its end, its docstring left out (the Parameters /
    Returns of a public function are not code)."""
    n = f.end_lineno - f.lineno + 1
    first = f.body[0]
    if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
            and isinstance(first.value.value, str):
        n -= (first.end_lineno or first.lineno) - first.lineno + 1
    return n


def test_no_module_of_the_shell_or_the_tools_is_over_400_lines():
    long = {str(p.relative_to(PACKAGE)): n for sub in ('ros', 'tools')
            for p in (PACKAGE / sub).rglob('*.py')
            if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, long


def test_no_function_is_over_60_lines_but_the_documented_exceptions():
    long, seen = {}, set()
    for p in _sources():
        for f in _functions(ast.parse(p.read_text())):
            name = f'{p.relative_to(PACKAGE)}:{f.name}'
            n = _length(f)
            if n > MAX_FUNCTION_LINES:
                seen.add(name)
                if name not in EXCEPTIONS:
                    long[name] = n
    assert not long, long
    assert EXCEPTIONS <= seen, f'no longer an exception: {EXCEPTIONS - seen}'


def _tools() -> set[str]:
    """The modules of setup.py's EXECUTABLES in motion_ctrl.tools (a command each)."""
    targets = [v.split(':')[0] for v in setup_table('EXECUTABLES').values()]
    return {t for t in targets if t.startswith('motion_ctrl.tools.')}


def test_no_tool_imports_another_tool():
    tools = _tools()
    assert {'motion_ctrl.tools.record', 'motion_ctrl.tools.autotune'} <= tools
    found = {}
    for p in (PACKAGE / 'tools').glob('*.py'):
        me = f'motion_ctrl.tools.{p.stem}'
        for n in ast.walk(ast.parse(p.read_text())):
            if isinstance(n, ast.ImportFrom) and n.module:
                names = [n.module] + [f'{n.module}.{a.name}' for a in n.names]
            elif isinstance(n, ast.Import):
                names = [a.name for a in n.names]
            else:
                continue
            other = sorted(m for m in names if m in tools and m != me)
            if other:
                found.setdefault(me, []).extend(other)
    assert not found, found
    # and nothing in tools/ but the tools themselves
    assert {f'motion_ctrl.tools.{p.stem}' for p in (PACKAGE / 'tools').glob('*.py')
            if p.stem != '__init__'} == tools
