"""Shared test setup: ROS network hygiene and imports from the source tree.

Fixtures shared by several test modules go below the setup block.
"""
import os
import pathlib
import sys

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# Tests import the source tree, not the copy installed in .venv.
if sys.path[0] != REPO_ROOT:
    sys.path.insert(0, REPO_ROOT)

# DDS discovery stays on this host, each test run gets its own domain (never 0) so parallel
# runs don't see each other, and the tests' participants the nodes' loopback-UDP profile (they
# find the nodes they start as soon as those come up), as every tool that starts its own nodes
# (motion_ctrl.ros.ros_env.private_domain). Set before any rclpy.init() and inherited by the
# nodes tests start as subprocesses.
from motion_ctrl.ros import ros_env  # noqa: E402

ros_env.private_domain()


def _compiled_stale() -> list[str]:
    """Modules whose source changed after scripts/bootstrap compiled them (setup.py COMPILED):
    the tree would run the old code. The extension module wins the import over its source. And
    those not compiled at all (unless MOTION_CTRL_COMPILE=0): a build that failed removed them,
    and the tree would run plain Python, slower, until the next change of a package file."""
    stale = []
    for base, _, files in os.walk(os.path.join(REPO_ROOT, 'motion_ctrl')):
        for f in files:
            if f.endswith('.so'):
                src = os.path.join(base, f.split('.')[0] + '.py')
                if os.path.getmtime(src) > os.path.getmtime(os.path.join(base, f)):
                    stale.append(os.path.relpath(src, REPO_ROOT))
    if os.environ.get('MOTION_CTRL_COMPILE', '1') != '0':
        missing = [src for src in setup_table('COMPILED') if not any(pathlib.Path(REPO_ROOT).glob(
            src.removesuffix('.py') + '.*.so'))]
        if missing:         # (bootstrap's stamp says the package is built: it was, once)
            pathlib.Path(REPO_ROOT, '.venv', '.package.stamp').unlink(missing_ok=True)
        stale += missing
    return stale


def setup_table(name: str):
    """A table of setup.py (COMPILED: the modules mypyc compiles; EXECUTABLES: the commands),
    read from its source: importing setup.py would run setup()."""
    import ast
    setup = ast.parse(pathlib.Path(REPO_ROOT, 'setup.py').read_text())
    return next(ast.literal_eval(n.value) for n in setup.body if isinstance(n, ast.Assign)
                and getattr(n.targets[0], 'id', '') == name)


_STALE = _compiled_stale()
if _STALE:
    # (scripts/test bootstraps first; this is for a bare `pytest` after an edit)
    print(f'conftest: {", ".join(_STALE)} changed since compiled, or not compiled: '
          'scripts/bootstrap', file=sys.stderr)
    import subprocess
    subprocess.run([os.path.join(REPO_ROOT, 'scripts', 'bootstrap')], check=True)


import subprocess  # noqa: E402

import pytest  # noqa: E402
from _pytest.mark.expression import Expression  # noqa: E402


# --- The core marker: tests that need no ROS -----------------------------------------------------
# test/ mirrors the package's layers (doc/architecture.md, "Layers"): the folders of the ROS-free
# layers (core, sim, analysis, canopen) and docs/ hold tests that are in-process, import no rclpy
# or message package and start no process. Every test in them is marked `core` (`scripts/test
# -m core`), except those marked `core_slow` (ROS-free as well, but a whole simulated test plan
# each, seconds apiece: they run with the full suite, or with `-m "core or core_slow"`). The
# folder says which file is which; while a test there runs, ROS packages refuse to import and
# starting a process fails (below), and test_core_without_ros imports each of them in an
# interpreter without ROS. ros/, tools/ and package/ hold the rest.
TEST_ROOT = pathlib.Path(__file__).resolve().parent
CORE_FOLDERS = ('core', 'sim', 'analysis', 'canopen', 'docs')


def core_files() -> list[pathlib.Path]:
    """The test files of CORE_FOLDERS."""
    return sorted(f for d in CORE_FOLDERS for f in (TEST_ROOT / d).glob('test_*.py'))


CORE_MARKS = ('core', 'core_slow')
# What a ROS-free test may not import: ROS 2's Python packages and messages, and what reads bags.
ROS_PACKAGES = ('rclpy', 'rcl_interfaces', 'sensor_msgs', 'std_msgs', 'std_srvs',
                'diagnostic_msgs', 'trajectory_msgs', 'rosgraph_msgs', 'builtin_interfaces',
                'ament_index_python', 'rosbags', 'mcap')


class NoRos:
    """A meta path finder that refuses ROS packages (those not imported yet)."""

    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ROS_PACKAGES:
            raise ImportError(f'{name}: a core test may not import ROS (conftest.CORE_FOLDERS)')
        return None


NO_ROS = NoRos()


def is_core_file(path) -> bool:
    """A file (or folder) of CORE_FOLDERS."""
    p = pathlib.Path(str(path)).resolve()
    return p.is_relative_to(TEST_ROOT) and len(p.relative_to(TEST_ROOT).parts) > 1 \
        and p.relative_to(TEST_ROOT).parts[0] in CORE_FOLDERS


def core_only(config) -> bool:
    """The -m expression selects no test outside CORE_FOLDERS (`-m core`, `-m "core or
    core_slow"`): decided for a test with no other mark and for one with every other mark."""
    expr = config.option.markexpr
    if not expr:
        return False
    compiled = Expression.compile(expr)
    return not any(compiled.evaluate(lambda name, /, **kw: other and name not in CORE_MARKS)
                   for other in (False, True))


def pytest_configure(config):
    # matplotlib's first import on a machine builds its font cache with `fc-list`, a process
    # a core test may not start: built here, before any test runs.
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.font_manager  # noqa: F401
    if core_only(config):
        # Nothing of this run may import ROS: the other test files are not even collected.
        sys.meta_path.insert(0, NO_ROS)


def pytest_ignore_collect(collection_path, config):
    if not core_only(config):
        return None
    p = pathlib.Path(str(collection_path)).resolve()
    if p.parent == TEST_ROOT and p.is_dir():         # a folder of the shell: not even read
        return True if p.name not in CORE_FOLDERS and p.name != 'data' else None
    if p.name.startswith('test_') and p.suffix == '.py' and not is_core_file(p):
        return True
    return None


@pytest.hookimpl(tryfirst=True)        # before -m deselects by the marks
def pytest_collection_modifyitems(config, items):
    for item in items:
        core = is_core_file(item.path)
        marks = {m.name for m in item.iter_markers() if m.name in CORE_MARKS}
        if marks and not core:
            raise pytest.UsageError(f'{item.nodeid}: marked {" and ".join(sorted(marks))} but '
                                    'its file is not in conftest.CORE_FOLDERS')
        if core and not marks:
            item.add_marker(pytest.mark.core)


def _no_process(*args, **kwargs):
    raise AssertionError('a core test starts no process (mark it fresh_interpreter if it runs '
                         'plain Python without ROS, or move it out of conftest.CORE_FOLDERS)')


@pytest.fixture(autouse=True)
def core_is_ros_free(request, monkeypatch):
    """A test of CORE_FOLDERS runs with ROS packages refusing to import (those not imported yet:
    in a `-m core` run, all) and may start no process (fresh_interpreter: plain Python)."""
    if not is_core_file(request.path):
        yield
        return
    if request.node.get_closest_marker('fresh_interpreter') is None:
        monkeypatch.setattr(subprocess.Popen, '_execute_child', _no_process)
    added = NO_ROS not in sys.meta_path
    if added:
        sys.meta_path.insert(0, NO_ROS)
    try:
        yield
    finally:
        if added:
            sys.meta_path.remove(NO_ROS)


# --- ROS 2 over-DDS fixtures (test_ros_*.py) -----------------------------------------------------


@pytest.fixture(scope='session', autouse=True)
def no_zombie_shm(request):
    """Before and after the run: the shared-memory files of DDS processes that died (some
    tests kill nodes on purpose) go, so their locked port mutexes cannot stall later nodes.
    Not between tests: the check takes each lock file's flock for a moment, and a participant
    starting meanwhile finds its lock taken (its shared-memory port then fails). Not in a
    `-m core` run: it starts no participant."""
    if core_only(request.config):
        yield
        return
    from motion_ctrl.ros import ros_env
    ros_env.clean_zombie_shm()
    yield
    ros_env.clean_zombie_shm()


@pytest.fixture(scope='module', autouse=True)
def module_domain(request):
    """Every test module on a ROS domain of its own (ros_env.spare_domain), set in the
    environment its node processes inherit: what one module's processes leave in shared memory
    (a killed or crashed participant's port, whose dead listener a later participant with the
    same port number inherits) cannot reach the next module's nodes. Yields the domain (None
    for a core module: it has no nodes)."""
    if is_core_file(request.path):
        yield None
        return
    from motion_ctrl.ros import ros_env
    saved = os.environ['ROS_DOMAIN_ID']
    domain = ros_env.spare_domain()
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    yield domain
    os.environ['ROS_DOMAIN_ID'] = saved


@pytest.fixture(scope='module')
def rclpy_session(module_domain):
    """rclpy (the default context) initialised for the module in this (test) process, on the
    module's domain; skips without rclpy."""
    rclpy = pytest.importorskip('rclpy')
    owned = not rclpy.ok()
    if owned:
        rclpy.init(domain_id=module_domain)
    yield rclpy
    if owned:
        rclpy.try_shutdown()


@pytest.fixture
def own_domain(rclpy_session, monkeypatch):
    """For a test that SIGKILLs nodes: a ROS domain of its own (ros_env.spare_domain: what a
    killed participant leaves in shared memory must not reach the later tests' nodes), set in
    the environment the test's node processes inherit, and an rclpy context on it for the
    test's own clients (not the session's participant, which would keep the dead ports open).
    Yields the context."""
    from motion_ctrl.ros import ros_env
    domain = ros_env.spare_domain()
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    context = rclpy_session.Context()
    rclpy_session.init(context=context, domain_id=domain)
    yield context
    context.try_shutdown()


@pytest.fixture(scope='module')
def node_env(module_domain):
    """Environment for node processes tests start: this run's ROS domain and discovery range
    (set above) and the source tree first on the path, like this process."""
    env = os.environ.copy()
    env['PYTHONPATH'] = os.pathsep.join(p for p in (REPO_ROOT, env.get('PYTHONPATH')) if p)
    return env


# -- a test whose servo link stalled --------------------------------------------------------------
# On this 2-core VM the DDS link between the plant and controller processes sometimes stalls for
# 20-60 ms; the controller then does what it must (FEEDBACK_FAULT, loop opened) and the plant's
# watchdog trips, and a test of something else (a trajectory's refusals, a parameter set) fails
# on a move that the fault ended. A fixture that runs such a link sets `item.servo_link_stalled`
# to the fault's log line when one came during the test, and a tool that reports its nodes' fault
# (draw) puts the line in the failure's text; such a test that failed runs once more (reported as
# a rerun, with the line). A test that fails without a stall, or fails again, fails.
def pytest_runtest_protocol(item, nextitem):
    from _pytest.runner import runtestprotocol

    import kit
    item.ihook.pytest_runtest_logstart(nodeid=item.nodeid, location=item.location)
    reports = runtestprotocol(item, nextitem=nextitem, log=False)
    failed = next((r for r in reports if r.failed), None)
    stalled = getattr(item, 'servo_link_stalled', '') or (
        failed is not None and kit.link_stall(item, str(failed.longrepr)))
    if stalled and failed is not None:
        writer = item.config.pluginmanager.get_plugin('terminalreporter')
        if writer is not None:
            writer.write_line(f'\nRERUN {item.nodeid}: the servo link stalled during it '
                              f'({stalled.strip()}); it failed with: '
                              f'{str(failed.longrepr).splitlines()[-1][:300]}', yellow=True)
        item.servo_link_stalled = ''
        item._initrequest()
        reports = runtestprotocol(item, nextitem=nextitem, log=False)
    for report in reports:
        item.ihook.pytest_runtest_logreport(report=report)
    item.ihook.pytest_runtest_logfinish(nodeid=item.nodeid, location=item.location)
    return True
