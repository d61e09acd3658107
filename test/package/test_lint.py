"""Lint and type checks as tests, as a ROS package runs ament_flake8 and ament_mypy: ruff
(ruff.toml) over the package, msg_defs, the tests, the launch file, setup.py and doc/conf.py;
mypy (setup.cfg [mypy]) over the package, msg_defs, the tests and setup.py (not launch/: mypy
would take that directory for the ROS `launch` package). scripts/ holds shell scripts only.
Each fails with the tool's own report."""
import subprocess
import sys

from conftest import REPO_ROOT


def _run(*args):
    return subprocess.run([sys.executable, '-m', *args], cwd=REPO_ROOT, capture_output=True,
                          text=True, timeout=300)


def test_ruff_clean():
    r = _run('ruff', 'check', 'motion_ctrl', 'msg_defs', 'test', 'launch', 'setup.py', 'doc')
    assert r.returncode == 0, r.stdout + r.stderr


def test_mypy_clean():
    r = _run('mypy', 'motion_ctrl', 'msg_defs', 'test', 'setup.py')
    assert r.returncode == 0, r.stdout + r.stderr
