"""Shared test setup: ROS network hygiene and imports from the source tree.

Fixtures shared by several test modules go below the setup block.
"""
import os
import sys

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# DDS discovery stays on this host, and each test run gets its own domain
# (never 0) so parallel runs don't see each other. Set before any rclpy.init()
# and inherited by the nodes tests start as subprocesses.
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
if os.environ.get('ROS_DOMAIN_ID', '0') in ('', '0'):
    # 1..101: higher domains' DDS ports reach Linux's ephemeral port range.
    os.environ['ROS_DOMAIN_ID'] = str(os.getpid() % 101 + 1)

# Tests import the source tree, not the copy installed in .venv.
if sys.path[0] != REPO_ROOT:
    sys.path.insert(0, REPO_ROOT)


# --- ROS 2 over-DDS fixtures (test_ros_*.py) -----------------------------------------------------
import pytest  # noqa: E402


@pytest.fixture(scope='session', autouse=True)
def no_zombie_shm():
    """Before and after the run: the shared-memory files of DDS processes that died (some
    tests kill nodes on purpose) go, so their locked port mutexes cannot stall later nodes.
    Not between tests: the check takes each lock file's flock for a moment, and a participant
    starting meanwhile finds its lock taken (its shared-memory port then fails)."""
    from motion_ctrl.ros import ros_env
    ros_env.clean_zombie_shm()
    yield
    ros_env.clean_zombie_shm()


@pytest.fixture(scope='module', autouse=True)
def module_domain():
    """Every test module on a ROS domain of its own (ros_env.spare_domain), set in the
    environment its node processes inherit: what one module's processes leave in shared memory
    (a killed or crashed participant's port, whose dead listener a later participant with the
    same port number inherits) cannot reach the next module's nodes. Yields the domain."""
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


@pytest.fixture(scope='session')
def slow_watchdog():
    """Controller parameters for DDS tests that are not about the encoder watchdog.

    Whenever a new participant or reader appears, Fast DDS's shared-memory transport
    health-checks the new reader's port inside the writer's (synchronous) publish: the plant's
    encoder stream stops for ~0.33 s, now and then up to 1 s (eProsima/Fast-DDS#6535, measured
    here; the probes, recorders and clients of the tests are such newcomers). The default 20 ms
    watchdog then rightly opens the loop (FEEDBACK_FAULT). A tick without a new sample holds
    the output, so a wide watchdog does not wind the loop up while it waits.
    """
    return {'feedback_timeout': 1.5}


@pytest.fixture(scope='module')
def node_env(module_domain):
    """Environment for node processes tests start: this run's ROS domain and discovery range
    (set above) and the source tree first on the path, like this process."""
    env = os.environ.copy()
    env['PYTHONPATH'] = os.pathsep.join(p for p in (REPO_ROOT, env.get('PYTHONPATH')) if p)
    return env
