"""Network hygiene, the executor, and shared-memory leftovers, for every motion_ctrl process
that uses ROS.

DDS discovery stays on this host unless the user chose otherwise
(ROS_AUTOMATIC_DISCOVERY_RANGE; Kilted ignores ROS_LOCALHOST_ONLY). Tools that start their own
nodes (demo, tests, benchmark) also get a ROS_DOMAIN_ID of their own when none (or 0) is set, so
parallel runs on one machine don't see each other, and the loopback-UDP profile of the nodes'
own processes (`loopback_udp`), so they find the nodes they start within half a second of their
coming up. Call before rclpy.init().
"""
import contextlib
import faulthandler
import fcntl
import filecmp
import itertools
import os
import re
import sys
import threading
import time


def local_discovery() -> None:
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


def private_domain() -> int:
    """Pick a domain from the pid (1..101: higher domains reach the ephemeral port range); this
    process's participants get the nodes' profile (loopback_udp)."""
    local_discovery()
    os.environ.update(loopback_udp())
    if os.environ.get('ROS_DOMAIN_ID', '0') in ('', '0'):
        os.environ['ROS_DOMAIN_ID'] = str(os.getpid() % 101 + 1)
    return int(os.environ['ROS_DOMAIN_ID'])


_spare_domains = itertools.count()
_spare_base: int | None = None


def spare_domain() -> int:
    """Another ROS domain than this process's, a new one per call (cycling through 1..101): for
    runs that must not meet the rest (lockstep), and for tests that SIGKILL nodes. A killed
    participant leaves its shared-memory port behind, and a participant that later gets the
    same port number on that domain inherits it with the dead listener's unread slots: sends to
    it are dropped as "port full", so service calls to it go unanswered (doc/design_notes.md,
    "Shared memory left by killed processes")."""
    global _spare_base
    if _spare_base is None:          # the process's own domain, as it was at the first call
        _spare_base = int(os.environ.get('ROS_DOMAIN_ID', '1'))
    return (_spare_base + 25 + next(_spare_domains)) % 101 + 1


# The Fast DDS profiles of motion_ctrl's processes (each file says why): tools and lockstep nodes
# announce loopback UDP locators only, no shared memory (loopback_udp.xml); the servo bus's
# processes also bind every socket to 127.0.0.1 (servo_bus.xml), under a discovery range that
# leaves the transports to the profile (SERVO_BUS_RANGE).
PROFILES_ENV = ('FASTDDS_DEFAULT_PROFILES_FILE', 'FASTRTPS_DEFAULT_PROFILES_FILE')
RANGE_ENV = 'ROS_AUTOMATIC_DISCOVERY_RANGE'
LOOPBACK_UDP = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'loopback_udp.xml')
SERVO_BUS = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'servo_bus.xml')
# rmw_fastrtps under LOCALHOST adds a UDPv4 transport of its own, bound to 0.0.0.0 and to every
# interface's address, beside the profile's (and every datagram then goes out twice); under
# SYSTEM_DEFAULT it adds nothing, and the profile's loopback-only transport is the only one.
SERVO_BUS_RANGE = 'SYSTEM_DEFAULT'


def loopback_udp(environ=os.environ) -> dict:
    """The environment entry that gives a process's participants the loopback-UDP profile; {}
    when the user chose a Fast DDS profile file of their own (theirs is kept). A copy of one of
    ours is not the user's: a tool run from the venv's install hands its nodes, which run from
    the source tree, the install's copy. Fast DDS reads it once per process, when its first
    participant is made: set it before the first node."""
    return _profile(LOOPBACK_UDP, environ)


def servo_bus(environ=os.environ) -> dict:
    """The environment of a servo bus process's participants: servo_bus.xml and the discovery
    range it needs (SERVO_BUS_RANGE); {} when the user chose a Fast DDS profile file of their
    own (the bus then runs on theirs, and their range)."""
    profile = _profile(SERVO_BUS, environ)
    return profile | {RANGE_ENV: SERVO_BUS_RANGE} if profile else {}


def _profile(path: str, environ) -> dict:
    if any(environ.get(k) and not profile_is_ours(environ[k]) for k in PROFILES_ENV):
        return {}
    return {PROFILES_ENV[0]: path}


def profile_is_ours(path: str) -> bool:
    """`path` is one of our profiles: this module's, or a file of the same name and bytes."""
    for mine in (LOOPBACK_UDP, SERVO_BUS):
        if path == mine:
            return True
        if os.path.basename(path) != os.path.basename(mine):
            continue
        try:
            if filecmp.cmp(path, mine, shallow=False):
                return True
        except OSError:
            pass
    return False


@contextlib.contextmanager
def environ(overrides: dict):
    """This process's environment with `overrides` (a value of None: unset) for the block: for
    what rcl reads at rclpy.init() (discovery range, static peers) and Fast DDS when a
    context's first node makes its participant (ROS_DISCOVERY_SERVER)."""
    saved = {k: os.environ.get(k) for k in overrides}
    try:
        _put(overrides)
        yield
    finally:
        _put(saved)


def _put(values: dict) -> None:
    for k, v in values.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


def executor(context=None):
    """The executor that holds a 1 kHz loop best here (measured: EventsExecutor, about half
    the CPU of SingleThreaded), SingleThreaded where rclpy has no EventsExecutor (before Jazzy
    7.1.4). Drive it with spin_once: in rclpy 9.1 EventsExecutor.spin() busy-waits without
    running timers or seeing signals."""
    # rclpy is imported here, not at the top: the tests' conftest imports this module in a
    # `-m core` run, where ROS packages refuse to import.
    try:
        from rclpy.experimental import EventsExecutor as Executor
    except ImportError:
        from rclpy.executors import SingleThreadedExecutor as Executor
    return Executor(context=context)


def realtime(priority: int) -> str | None:
    """Run every thread of this process under SCHED_FIFO at `priority` (0: leave the normal
    scheduling); threads made later inherit it from the thread that makes them. Returns why it
    could not be done (no CAP_SYS_NICE or rtprio limit, not Linux), or None.

    A servo loop on a general-purpose kernel runs in a real-time thread (LinuxCNC's servo-thread,
    PMAC's real-time interrupt). Here it also keeps the DDS threads of the node prompt: a Fast
    DDS shared-memory port whose listener thread is not scheduled in time looks stalled to
    another participant's health check, and the node's streams then pause for the check's
    333 ms timeout (eProsima/Fast-DDS#6535) whenever a ROS tool joins the graph. Measured in
    doc/design_notes.md.
    """
    if priority <= 0:
        return None
    if not hasattr(os, 'sched_setscheduler'):
        return 'real-time scheduling is not available on this system'
    param = os.sched_param(priority)
    try:
        tids = [int(t) for t in os.listdir('/proc/self/task')]
    except OSError:
        tids = [0]
    try:
        for tid in tids:
            try:
                os.sched_setscheduler(tid, os.SCHED_FIFO, param)
            except ProcessLookupError:
                pass                    # (a thread that ended meanwhile)
    except PermissionError:
        return (f'cannot run at real-time priority {priority} (SCHED_FIFO needs CAP_SYS_NICE or '
                f'`ulimit -r {priority}`): normal scheduling, where CPU load and ROS tools '
                f'joining the graph can delay encoder samples past feedback_timeout')
    return None


SHM_DIR = '/dev/shm'
_SHM_LOCK = re.compile(r'^fastdds_(port\d+|[0-9a-f]{16})_(el|sl)$')


def clean_zombie_shm(shm_dir: str = SHM_DIR) -> int:
    """Remove the shared-memory files of Fast DDS participants whose process is gone, as
    `fastdds shm clean` does (that tool is not in the pip wheels). Returns the files removed.

    Every segment and port has a lock file (`_el`/`_sl`) that its owner holds with flock while
    it lives; one nobody holds belongs to a dead process (a SIGKILL, a crash). Left behind, a
    port's named mutex can stay locked, and every process that later opens that port number
    waits 2 s for it (a node can then take tens of seconds to start and to exit). Files of live
    processes, of any run on this machine, are left alone.
    """
    try:
        names = os.listdir(shm_dir)
    except FileNotFoundError:
        return 0
    removed = 0
    for name in names:
        m = _SHM_LOCK.match(name)
        if not m or _locked(os.path.join(shm_dir, name)):
            continue
        base = f'fastdds_{m.group(1)}'
        for f in (name, base, f'sem.{base}_mutex'):
            try:
                os.remove(os.path.join(shm_dir, f))
                removed += 1
            except OSError:
                pass
    return removed


def _locked(path: str) -> bool:
    try:
        with open(path, 'ab') as f:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return False
    except OSError:
        return True


def leave_if_stuck(name: str, after: float, code: int = 0, why: str = 'stop') -> None:
    """Start a daemon thread that exits this process with `code` `after` s from now if it is
    still here, saying so and where every thread was (faulthandler) on stderr: ROS's teardown
    of a node and its DDS participant can hang (in rclpy's EventsExecutor.shutdown(), among
    others) and must not keep a process alive whose work is done (doc/design_notes.md,
    "Stopping a node: the deadline and the watchdog")."""
    def leave():
        time.sleep(after)
        print(f'{name}: {why} took over {after:g} s (ROS teardown stuck); leaving without it. '
              f'Threads at that moment:', file=sys.stderr, flush=True)
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
        sys.stderr.flush()
        os._exit(code)
    threading.Thread(target=leave, daemon=True).start()
