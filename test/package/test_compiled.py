"""The servo tick compiled by mypyc (setup.py COMPILED) is the plain Python it is compiled from:
the tree that the tests import runs the compiled modules (scripts/bootstrap copies them there),
and a slide run with them matches, float for float, the same run on the plain sources."""
import os
import shutil
import subprocess
import sys

import pytest

from conftest import REPO_ROOT, setup_table


# The run compared: the headline table (every configuration, the leadscrew calibration
# included) and every float of a harness trace of the 1-inch move and back, as a digest.
RUN = r'''
import hashlib, importlib, sys
from motion_ctrl.core.registers import INCH
from motion_ctrl.sim.harness import Harness
from motion_ctrl.tools import scenarios
compiled = [m for m in sys.argv[1:] if importlib.import_module(m).__file__.endswith('.so')]
print('compiled:', len(compiled))
print(scenarios.format_table(scenarios.table()))
h = Harness()
h.move(INCH)
h.move(0.0)
tr = h.trace
print(hashlib.sha256(repr((tr.command, tr.actual, tr.motor, tr.load, tr.output, tr.status,
                           tr.following_error)).encode()).hexdigest())
'''


def compiled_modules() -> list[str]:
    """setup.py's COMPILED, as module names."""
    return [p[:-3].replace('/', '.') for p in setup_table('COMPILED')]


def run(root, env) -> str:
    out = subprocess.run([sys.executable, '-c', RUN, *compiled_modules()], cwd=root, env=env,
                         capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout


def test_the_tree_runs_the_servo_tick_compiled():
    try:
        import mypyc  # noqa: F401
    except ImportError:
        pytest.skip('no mypyc here: the package was built as plain Python')
    if os.environ.get('MOTION_CTRL_COMPILE') == '0':
        pytest.skip('MOTION_CTRL_COMPILE=0: built as plain Python')
    import importlib
    plain = [m for m in compiled_modules()
             if not importlib.import_module(m).__file__.endswith('.so')]
    assert not plain, f'run from source, not compiled (scripts/bootstrap compiles): {plain}'


def test_compiled_and_plain_python_run_the_same_slide(tmp_path):
    env = dict(os.environ)
    env.pop('PYTHONPATH', None)
    # The plain sources: the package's .py files alone, so no extension module can load.
    for pkg in ('motion_ctrl', 'msg_defs'):
        shutil.copytree(os.path.join(REPO_ROOT, pkg), tmp_path / pkg,
                        ignore=shutil.ignore_patterns('*.so', '__pycache__'))
    plain = run(tmp_path, env).splitlines()
    compiled = run(REPO_ROOT, env).splitlines()
    print(compiled[0], f'of {len(compiled_modules())}; plain sources: {plain[0]}')
    assert plain[0] == 'compiled: 0'
    assert plain[1:] == compiled[1:]
