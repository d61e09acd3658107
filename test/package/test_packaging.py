"""Packaging: launch file, executables, and the tree that scripts/bootstrap installs."""
import ast
import glob
import os
import runpy
import shutil
import subprocess
import sys
from importlib import metadata

import pytest

from conftest import REPO_ROOT

PACKAGE = 'motion_ctrl'

# The contract: `ros2 run motion_ctrl NAME` for each of these names (README's executables);
# which module serves each is setup.py's business, checked below to exist.
EXPECTED_NAMES = {'controller', 'plant', 'notch', 'demo', 'scenarios', 'tune', 'benchmark',
                  'record', 'report', 'soak', 'draw', 'calibrate', 'identify', 'autotune',
                  'virtual_drive'}
LAUNCH_ARGUMENTS = {'controller_params', 'plant_params', 'use_sim_time', 'axes', 'hardware'}


def _setup_kwargs(monkeypatch, cwd, argv):
    """Run setup.py with setuptools.setup() stubbed; return its keyword arguments."""
    import setuptools
    captured = {}
    monkeypatch.setattr(setuptools, 'setup', lambda **kw: captured.update(kw))
    monkeypatch.chdir(cwd)
    monkeypatch.setattr(sys, 'argv', ['setup.py'] + argv)
    runpy.run_path(os.path.join(cwd, 'setup.py'))
    return captured


def _console_scripts(kwargs):
    entries = kwargs['entry_points']['console_scripts']
    return dict((part.strip() for part in e.split('=', 1)) for e in entries)


def _calls(tree, func_name):
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call)
            and getattr(n.func, 'id', getattr(n.func, 'attr', None)) == func_name]


def _installed_prefix():
    """sys.prefix when it holds motion_ctrl's install; skip if not a project venv."""
    prefix = sys.prefix
    if os.path.isdir(os.path.join(prefix, 'share', PACKAGE)):
        return prefix
    if os.path.realpath(prefix) == os.path.realpath(os.path.join(REPO_ROOT, '.venv')):
        pytest.fail('running in the project .venv but share/motion_ctrl is missing: '
                    'scripts/bootstrap did not install the package data')
    pytest.skip(f'not running in a venv made by scripts/bootstrap ({prefix} has no '
                f'share/{PACKAGE}); run scripts/test')


# --- launch file -------------------------------------------------------------

def test_launch_file_compiles_and_names_nodes_and_arguments():
    path = os.path.join(REPO_ROOT, 'launch', 'slide.launch.py')
    with open(path) as f:
        source = f.read()
    code = compile(source, path, 'exec')
    assert code is not None
    tree = ast.parse(source)
    assert any(isinstance(n, ast.FunctionDef) and n.name == 'generate_launch_description'
               for n in tree.body)

    declared = {ast.literal_eval(c.args[0]) for c in _calls(tree, 'DeclareLaunchArgument')}
    assert declared == LAUNCH_ARGUMENTS

    nodes = {}
    for call in _calls(tree, 'Node'):
        kw = {k.arg: k.value for k in call.keywords}
        assert ast.literal_eval(kw['package']) == PACKAGE
        nodes[ast.literal_eval(kw['executable'])] = ast.literal_eval(kw['name'])
    assert nodes == {'controller': 'controller', 'plant': 'plant'}
    assert set(nodes) <= EXPECTED_NAMES


# --- setup.py ----------------------------------------------------------------

def test_setup_executables_are_the_entry_points(monkeypatch):
    kwargs = _setup_kwargs(monkeypatch, REPO_ROOT, ['--name'])
    assert set(_console_scripts(kwargs)) == EXPECTED_NAMES
    # Under colcon (no wheel) the real scripts go to lib/motion_ctrl: no shims.
    assert not [d for d, _ in kwargs['data_files'] if d.startswith('lib/')]
    assert kwargs['name'] == PACKAGE
    with open(os.path.join(REPO_ROOT, 'package.xml')) as f:
        assert f'<version>{kwargs["version"]}</version>' in f.read()


def test_entry_point_targets_exist_in_source(monkeypatch):
    """Each console script's module exists and defines its function (not imported)."""
    missing = []
    kwargs = _setup_kwargs(monkeypatch, REPO_ROOT, ['--name'])
    for name, target in _console_scripts(kwargs).items():
        module, func = target.split(':')
        path = os.path.join(REPO_ROOT, *module.split('.')) + '.py'
        if not os.path.isfile(path):
            missing.append(f'{name}: {path} missing')
            continue
        with open(path) as f:
            tree = ast.parse(f.read(), path)
        if not any(isinstance(n, ast.FunctionDef) and n.name == func for n in tree.body):
            missing.append(f'{name}: {module} has no top-level {func}()')
    assert not missing, '\n'.join(missing)


def test_wheel_build_adds_executable_shims(monkeypatch, tmp_path):
    shutil.copy(os.path.join(REPO_ROOT, 'setup.py'), tmp_path)
    monkeypatch.setenv('MOTION_CTRL_COMPILE', '0')     # (the shims only: no mypyc build here)
    kwargs = _setup_kwargs(monkeypatch, str(tmp_path), ['bdist_wheel'])
    shims = [f for d, files in kwargs['data_files'] if d == f'lib/{PACKAGE}' for f in files]
    assert {os.path.basename(f) for f in shims} == EXPECTED_NAMES
    for shim in shims:
        assert os.access(tmp_path / shim, os.X_OK), shim

    # A shim reached through a symlink (as ros2 run may) execs <prefix>/bin/NAME
    # with the arguments unchanged.
    prefix = tmp_path / 'prefix'
    (prefix / 'lib' / PACKAGE).mkdir(parents=True)
    (prefix / 'bin').mkdir()
    shutil.copy(tmp_path / 'build' / 'shims' / 'plant', prefix / 'lib' / PACKAGE / 'plant')
    target = prefix / 'bin' / 'plant'
    target.write_text('#!/bin/sh\necho "plant:$#:$1:$2"\n')
    target.chmod(0o755)
    (tmp_path / 'link').symlink_to(prefix / 'lib' / PACKAGE / 'plant')
    out = subprocess.run([str(tmp_path / 'link'), 'a b', '--ros-args'],
                         capture_output=True, text=True, check=True).stdout
    assert out == 'plant:2:a b:--ros-args\n'


# --- installed tree (after scripts/bootstrap) --------------------------------

def test_installed_tree_is_complete():
    prefix = _installed_prefix()
    for rel in (f'share/ament_index/resource_index/packages/{PACKAGE}',
                f'share/{PACKAGE}/package.xml',
                f'share/{PACKAGE}/launch/slide.launch.py'):
        assert os.path.isfile(os.path.join(prefix, rel)), rel
    for src in glob.glob(os.path.join(REPO_ROOT, 'params', '*.yaml')):
        rel = f'share/{PACKAGE}/params/{os.path.basename(src)}'
        assert os.path.isfile(os.path.join(prefix, rel)), rel

    libdir = os.path.join(prefix, 'lib', PACKAGE)
    for name in EXPECTED_NAMES:
        exe = os.path.join(libdir, name)
        assert os.path.isfile(exe) and os.access(exe, os.X_OK), f'{exe} not executable'
        target = os.path.join(prefix, 'bin', name)
        assert os.path.isfile(target) and os.access(target, os.X_OK), f'{target} missing'
        with open(exe) as f:
            text = f.read()
        if text.startswith('#!/bin/sh'):  # pip-path shim
            assert f'/../../bin/{name}"' in text


def test_installed_package_has_its_data():
    """The Fast DDS profiles are installed beside the module that names them."""
    _installed_prefix()
    for name in ('loopback_udp.xml', 'servo_bus.xml'):
        path = metadata.distribution(PACKAGE).locate_file(f'{PACKAGE}/ros/{name}')
        assert os.path.isfile(str(path)), path


def test_installed_entry_points_match():
    _installed_prefix()
    dist = metadata.distribution(PACKAGE)
    scripts = {ep.name for ep in dist.entry_points if ep.group == 'console_scripts'}
    assert scripts == EXPECTED_NAMES


def test_ament_index_finds_package(monkeypatch):
    prefix = _installed_prefix()
    packages = pytest.importorskip('ament_index_python.packages')
    monkeypatch.setenv('AMENT_PREFIX_PATH', prefix)
    assert packages.get_package_prefix(PACKAGE) == prefix
    assert packages.get_package_share_directory(PACKAGE) == os.path.join(
        prefix, 'share', PACKAGE)
