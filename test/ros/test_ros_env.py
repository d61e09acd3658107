"""ros_env: the shared-memory leftovers of dead DDS processes are removed, live ones kept; the
loopback-UDP profile is set unless the user chose a profile file of their own."""
import fcntl
import shutil

from motion_ctrl.ros import ros_env


def test_clean_zombie_shm_removes_only_what_dead_processes_left(tmp_path):
    def touch(*names):
        for n in names:
            (tmp_path / n).write_bytes(b'')
    dead_segment = ('fastdds_0123456789abcdef', 'fastdds_0123456789abcdef_el')
    dead_port = ('fastdds_port7411', 'fastdds_port7411_el', 'sem.fastdds_port7411_mutex')
    live_segment = ('fastdds_fedcba9876543210', 'fastdds_fedcba9876543210_el')
    live_port = ('fastdds_port7413', 'fastdds_port7413_sl', 'sem.fastdds_port7413_mutex')
    others = ('lttng-ust-wait-6', 'fastdds_port7415')          # not ours / no lock file
    touch(*dead_segment, *dead_port, *live_segment, *live_port, *others)
    # A live owner holds its lock file (here: this process, on another open file description).
    held = [open(tmp_path / name, 'ab') for name in (live_segment[1], live_port[1])]
    for f in held:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    try:
        assert ros_env.clean_zombie_shm(str(tmp_path)) == 5
    finally:
        for f in held:
            f.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(live_segment + live_port + others)
    assert ros_env.clean_zombie_shm(str(tmp_path / 'missing')) == 0


def test_the_loopback_profile_keeps_a_users_file_but_not_a_copy_of_its_own(tmp_path):
    """A tool run from the venv's install hands its nodes (run from the source tree) its own
    copy of loopback_udp.xml: that is not the user's file, the nodes keep the profile (before,
    every demo's bus said "the servo bus runs on your Fast DDS profile file")."""
    ours = {ros_env.PROFILES_ENV[0]: ros_env.LOOPBACK_UDP}
    assert ros_env.loopback_udp({}) == ours
    copy = tmp_path / 'site-packages' / 'loopback_udp.xml'
    copy.parent.mkdir()
    shutil.copy(ros_env.LOOPBACK_UDP, copy)
    assert ros_env.loopback_udp({ros_env.PROFILES_ENV[1]: str(copy)}) == ours
    users = tmp_path / 'loopback_udp.xml'                  # the same name, another profile
    users.write_text('<profiles/>')
    assert ros_env.loopback_udp({ros_env.PROFILES_ENV[0]: str(users)}) == {}
    assert ros_env.loopback_udp({ros_env.PROFILES_ENV[0]: str(tmp_path / 'mine.xml')}) == {}


def test_the_servo_bus_profile_comes_with_the_range_that_leaves_it_the_transports(tmp_path):
    """The servo bus's processes get servo_bus.xml and SYSTEM_DEFAULT (under LOCALHOST
    rmw_fastrtps would add a transport bound to 0.0.0.0 beside it); a tool's loopback_udp.xml
    handed down is ours and gives way; a user's own profile file is kept, range and all."""
    ours = {ros_env.PROFILES_ENV[0]: ros_env.SERVO_BUS, 'ROS_AUTOMATIC_DISCOVERY_RANGE':
            'SYSTEM_DEFAULT'}
    assert ros_env.servo_bus({}) == ours
    assert ros_env.servo_bus({ros_env.PROFILES_ENV[0]: ros_env.LOOPBACK_UDP}) == ours
    users = tmp_path / 'mine.xml'
    users.write_text('<profiles/>')
    assert ros_env.servo_bus({ros_env.PROFILES_ENV[0]: str(users)}) == {}
