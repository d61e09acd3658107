"""Tuned from another machine (issue 27): a "controller PC" and a "laptop" as two network
namespaces joined by a veth pair, made and removed here (two_hosts_kit.Hosts; nothing is sent
on this machine's own interfaces), ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET inside both.

The controller PC runs plant and controller as a user would, and moves the axis back and forth
with the shipped 20 ms watchdog; the laptop's tools reach the nodes through the relays
(servo_bus.relay): parameters, echo, a recording of the servo streams, the link down for 5 s,
and a `command` and an `encoders` of its own, which move nothing.
"""
from __future__ import annotations

import json
import os
import pathlib
import shutil
import subprocess
import sys
import time

import pytest

pytest.importorskip('rclpy')

from two_hosts_kit import CONTROLLER_IP, Hosts  # noqa: E402

KIT = pathlib.Path(__file__).with_name('two_hosts_kit.py')
ROOT = KIT.parents[2]

pytestmark = [
    pytest.mark.skipif(os.geteuid() != 0 or shutil.which('ip') is None,
                       reason='makes network namespaces: needs root and iproute2'),
    pytest.mark.timeout(240)]


# The two recipes a user follows (README, "Tuning from another machine"): discovery opened to
# the subnet (multicast), or a discovery server on the controller PC.
RECIPES = {
    'subnet': {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'},
    'discovery_server': {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
                         'ROS_DISCOVERY_SERVER': f'{CONTROLLER_IP}:11811'}}
LAPTOP = {'discovery_server': {'ROS_SUPER_CLIENT': 'TRUE'}}   # (as `ros2` CLI tools need)


def _env(tmp_path, domain: int, recipe: str) -> dict:
    env = dict(os.environ)
    for k in ('FASTDDS_DEFAULT_PROFILES_FILE', 'FASTRTPS_DEFAULT_PROFILES_FILE',
              'MOTION_CTRL_SERVO_DOMAIN'):
        env.pop(k, None)
    return env | RECIPES[recipe] | {
        'ROS_DOMAIN_ID': str(domain), 'TWO_HOSTS_DIR': str(tmp_path),
        'PYTHONPATH': os.pathsep.join([str(ROOT), str(ROOT / 'test')])}


def _discovery_server(hosts: Hosts, env: dict, log: pathlib.Path) -> subprocess.Popen:
    """Fast DDS's discovery server on the controller PC: what `fastdds discovery -l IP -p
    PORT` runs (its Python front end wants psutil, which nothing else here needs: the binary
    itself, with the front end's server command, 42; the pip wheel's binary finds its
    libraries through LD_LIBRARY_PATH only)."""
    venv = pathlib.Path(sys.executable).parents[1]
    libs = [venv / 'lib', *venv.glob('lib/python3*/site-packages/ros_fastdds.libs')]
    return hosts.popen(hosts.controller, [
        str(venv / 'bin' / 'fast-discovery-server'), '42', '-l', CONTROLLER_IP, '-p', '11811'],
        env | {'LD_LIBRARY_PATH': os.pathsep.join(map(str, libs))},
        stdout=log.open('w'), stderr=subprocess.STDOUT)


def _wait_file(path: pathlib.Path, proc: subprocess.Popen, timeout: float) -> None:
    end = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, f'{path.name}: the program ended ({proc.returncode})'
        assert time.monotonic() < end, f'no {path.name} within {timeout} s'
        time.sleep(0.1)


def _wait_text(path: pathlib.Path, text: str, proc: subprocess.Popen, timeout: float) -> None:
    end = time.monotonic() + timeout
    while text not in (path.read_text() if path.exists() else ''):
        assert proc.poll() is None, f'{path.name}: {path.read_text()}'
        assert time.monotonic() < end, f'no {text!r} in {path.name} within {timeout} s'
        time.sleep(0.1)


@pytest.mark.parametrize('recipe', list(RECIPES))
def test_tuned_from_a_laptop_the_loop_unaffected(tmp_path, own_domain, recipe):
    hosts = Hosts(str(os.getpid() % 10000))
    env = _env(tmp_path, int(os.environ['ROS_DOMAIN_ID']), recipe)
    ctl_out, lap_out = tmp_path / 'controller_pc.json', tmp_path / 'laptop.json'
    try:
        if recipe == 'discovery_server':
            server = _discovery_server(hosts, env, tmp_path / 'discovery_server.log')
            _wait_text(tmp_path / 'discovery_server.log', 'Server started', server, 10.0)
        pc = hosts.popen(hosts.controller, [sys.executable, str(KIT), 'controller_pc',
                                            str(ctl_out), '150', str(tmp_path)], env)
        _wait_file(pathlib.Path(f'{ctl_out}.ready'), pc, 60.0)
        lap = hosts.popen(hosts.laptop, [
            sys.executable, str(KIT), 'laptop', str(lap_out), 'discover', 'params_round',
            'echo:3', 'record:10', 'listen:12', 'echo:2', 'commander:6'],
            env | LAPTOP.get(recipe, {}))
        # the link down for 5 s while the laptop's tools are attached (and echo)
        _wait_file(pathlib.Path(f'{lap_out}.record'), lap, 90.0)
        time.sleep(2.0)
        t_down = time.time()
        hosts.link(False)
        time.sleep(5.0)
        t_up = time.time()
        hosts.link(True)
        assert lap.wait(90) == 0, (tmp_path / 'laptop.json').read_text()
        pathlib.Path(f'{ctl_out}.stop').touch()
        assert pc.wait(30) == 0
    finally:
        hosts.close()
    pc_found, found = json.loads(ctl_out.read_text()), json.loads(lap_out.read_text())
    print(json.dumps(found | {'moves': pc_found['moves']}, indent=1)[:6000])
    logs = {n: (tmp_path / f'{n}.log').read_text() for n in ('controller', 'plant')}
    # the loop: no fault, while the laptop did all that (and after its `command` and
    # `encoders`, refused)
    assert len(pc_found['moves']) >= 15 and pc_found['faults'] == []
    # the servo bus's processes on loopback only; the relays are what the laptop reaches
    beyond = pc_found['beyond_loopback']
    assert sorted(beyond) == sorted(f'{n} {k}' for n in ('plant', 'controller')
                                    for k in ('bridge', 'loop', 'relay')), beyond
    assert {k: v for k, v in beyond.items() if 'relay' not in k} == {
        f'{n} {k}': [] for n in ('plant', 'controller') for k in ('bridge', 'loop')}
    assert all(beyond[f'{n} relay'] for n in ('plant', 'controller'))
    # the laptop: parameters, echo, the recording
    assert found['discover']['services']
    p = found['params_round']
    assert p['set'] and p['kp_after_set'] == pytest.approx(p['kp'] * 1.01)
    assert p['dumped'] > 50 and p['loaded'] > 40 and p['load_refused'] == [], p
    # (an echo in Python, as `ros2 topic echo`, keeps a history of 10 and takes what its CPU
    # lets it: 1400-2900 of the 3000 in 3 s here)
    assert found['echo']['joint_states'] > 300 and found['echo_2']['joint_states'] > 0
    assert found['echo']['status_words'] >= 25 and found['echo_2']['status_words'] >= 10
    assert found['record']['rc'] == 0, found['record']['output']
    # the link down and up: the laptop's stream paused while it was down (from when what was
    # already on its way ran out) and came back after it came up (0.16 s after, here)
    across = [(a, b) for a, b in found['listen']['gaps'] if t_down <= a < t_up <= b]
    assert across and across[0][1] - t_up < 6.0, (found['listen']['gaps'], t_down, t_up)
    # a command and an encoders reading of its own move nothing, and are named (in the logs
    # first: a status missing on the laptop then says whether the relay refused at all)
    for node, what in (('plant', 'command'), ('controller', 'encoders')):
        assert f'/{what} from /laptop_tools refused' in logs[node], logs[node][-2000:]
    sources = {(n, level) for n, level, keys in found['commander']['sources']
               if any('laptop_tools' in k for k in keys)}
    assert {('plant: command source', 1), ('controller: encoders source', 1)} <= sources, \
        found['commander']
    # Every move within a count, unless the machine could not give the loop its ticks: this
    # rig runs both hosts' ten processes on the VM's two cores, and when the loop itself, at
    # SCHED_FIFO 50, lost more than 1.5 % of its ticks in a second (the VM's host taking the
    # cores: 957-983 Hz seen in some runs) a miss is the machine's; at full rate it fails.
    rates = [float(d['rate_hz']) for v in found.values() for d in v.get('loop', [])]
    off = [m for m in pc_found['moves'] if m is None or abs(m) > 1.0]
    if off and min(rates) < 985.0:
        pytest.xfail(f'the loop was held up on this machine ({min(rates):.0f} Hz in one '
                     f'second): moves {off}')
    assert not off, pc_found['moves']
    # The recording complete: through the two relays' copies, with the streams kept 10 s deep
    # on the way (bridge.STREAM_DEPTH, record --depth). 1 s deep, a 10 s recording lost 2-28 %
    # in some runs: the copies, at normal priority on two cores shared with everything else
    # here, fell up to 2 s behind.
    overruns = [int(float(d['overruns_total'])) for d in found['echo']['loop'][-1:]
                + found['record']['loop']]
    lacks = _incomplete(pathlib.Path(found['record']['bag']), overruns[-1] - overruns[0])
    assert not lacks, lacks


def _incomplete(bag: pathlib.Path, skipped: int) -> list[str]:
    """What the recording lacks: its servo streams must hold one message a servo period from
    first to last, but for the ticks the controller's loop itself skipped (`skipped`, its own
    count over the recording: /diagnostics overruns_total; the plant's `encoders`, whose ticks
    nothing counts, within 2 %), over more than 2 s."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from motion_ctrl.bags.reader import parse_joint_state
    stamps: dict[str, list[float]] = {}
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_KILTED)) as reader:
        for conn, _t, raw in reader.messages():
            if conn.msgtype == 'sensor_msgs/msg/JointState':
                stamps.setdefault(conn.topic, []).append(parse_joint_state(raw)[0] * 1e-9)
    lacks = []
    for topic in ('/joint_states', '/command', '/encoders'):
        t = sorted(stamps.get(topic, []))
        missing = sum(round(b - a, 3) * 1000 - 1 for a, b in zip(t, t[1:]))
        span = t[-1] - t[0] if t else 0.0
        line = (f'{topic}: {len(t)} messages over {span:.3f} s, {missing:.0f} periods without '
                f'one (the loop skipped {skipped})')
        print(line)
        if span <= 2.0 or missing > (skipped if topic != '/encoders' else 0.02 * len(t)):
            lacks.append(line)
    return lacks
