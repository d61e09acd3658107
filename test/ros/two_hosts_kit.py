"""Two hosts on one machine (test_two_hosts.py): network namespaces joined by a veth pair,
made and removed by the test, and the two programs that run inside them.

    python test/ros/two_hosts_kit.py controller_pc OUT.json SECONDS LOG_DIR
    python test/ros/two_hosts_kit.py laptop OUT.json PHASES...

`controller_pc`: plant and controller (on their servo bus, your domain reaching the subnet),
and a client that moves the axis back and forth between two targets until OUT.json.stop
appears (at most SECONDS); writes each move's landing error [counts] and the status words'
faults. `laptop`: the tools of another
host, one phase after another (each a function below), its findings in OUT.json.
"""
from __future__ import annotations

import contextlib
import json
import os
import pathlib
import subprocess
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import JointState
from std_msgs.msg import UInt32

import msg_defs as md

ROOT = pathlib.Path(__file__).resolve().parents[2]
CONTROLLER_IP, LAPTOP_IP = '10.231.7.1', '10.231.7.2'
REALTIME = 50                # SCHED_FIFO priority of the controller PC's loops
# The servo streams the laptop records: the loop's output and input (each relayed twice on
# the controller PC; all seven were more than this 2-core VM, which also plays the laptop,
# could copy: test_two_hosts.py says what was lost)
RECORDED = ['joint_states', 'command', 'encoders', 'x/status']


# -- the namespaces ------------------------------------------------------------------------------
class Hosts:
    """Two network namespaces, `controller` and `laptop`, joined by a veth pair whose ends are
    made inside them: addresses, routes and the multicast route exist only there, and nothing
    is sent on the machine's own interfaces. `close` removes them (and what runs in them)."""

    def __init__(self, tag: str):
        self.controller, self.laptop = f'mc2h_c_{tag}', f'mc2h_l_{tag}'
        self.veth = {self.controller: f'mc2hc{tag}'[:15], self.laptop: f'mc2hl{tag}'[:15]}
        try:
            self._ip('netns', 'add', self.controller)
            self._ip('netns', 'add', self.laptop)
            c, lp = self.veth[self.controller], self.veth[self.laptop]
            self._ip('link', 'add', c, 'netns', self.controller, 'type', 'veth', 'peer',
                     'name', lp, 'netns', self.laptop)
            for ns, ip in ((self.controller, CONTROLLER_IP), (self.laptop, LAPTOP_IP)):
                self._ip('-n', ns, 'link', 'set', 'lo', 'up')
                self._ip('-n', ns, 'addr', 'add', f'{ip}/24', 'dev', self.veth[ns])
                self._ip('-n', ns, 'link', 'set', self.veth[ns], 'up')
                # (DDS discovery's multicast goes where the route says: over the veth)
                self._ip('-n', ns, 'route', 'add', '224.0.0.0/4', 'dev', self.veth[ns])
        except BaseException:
            self.close()
            raise

    @staticmethod
    def _ip(*args: str) -> None:
        subprocess.run(['ip', *args], check=True, capture_output=True, text=True)

    def link(self, up: bool) -> None:
        """The laptop's end of the link taken down or brought up."""
        self._ip('-n', self.laptop, 'link', 'set', self.veth[self.laptop],
                 'up' if up else 'down')

    def popen(self, ns: str, args: list[str], env: dict, **kw) -> subprocess.Popen:
        return subprocess.Popen(['ip', 'netns', 'exec', ns, *args], env=env, **kw)

    def close(self) -> None:
        for ns in (self.controller, self.laptop):
            pids = subprocess.run(['ip', 'netns', 'pids', ns], capture_output=True,
                                  text=True).stdout.split()
            for pid in pids:
                with contextlib.suppress(ProcessLookupError, ValueError):
                    os.kill(int(pid), 9)
            subprocess.run(['ip', 'netns', 'del', ns], capture_output=True)


# -- the controller PC ---------------------------------------------------------------------------
def controller_pc(out: str, seconds: str, log_dir: str) -> None:
    from kit import COUNT, INCH, ip_sockets
    from motion_ctrl.ros.client import FAULTS, SlideClient
    from motion_ctrl.ros.processes import start_slide
    # (the loops at a real-time priority, as on a controller PC that must not let what it
    # serves to other hosts slow them: here the "laptop" shares its two cores)
    rt = {'realtime_priority': REALTIME}
    plant, controller = start_slide(rt, rt, log_dir=log_dir)
    rclpy.init()
    client = SlideClient(name='mover')
    moves, words, sockets = [], [], {}
    try:
        assert client.wait_ready(30.0), client.not_ready()
        pathlib.Path(out + '.ready').touch()
        end, target = time.monotonic() + float(seconds), INCH
        stop = pathlib.Path(out + '.stop')            # (the test: the laptop is done)
        while time.monotonic() < end and not stop.exists():
            target = 2 * INCH if target == INCH else INCH
            mark = len(client.status_log['x'])
            done = client.move({'x': target}, timeout=10.0)
            # (the true position from a plant_states sample stamped after MOTION_DONE: through
            # the relay, its copy can lag seconds on this machine's two shared cores)
            fresh = done is not None and client.truth_since(client.done_at, 12.0)
            moves.append((client.load_position() - target) / COUNT if fresh else None)
            words += [w for _, w in client.status_log['x'][mark:]]
            client.spin_for(0.3)
        sockets = {f'{n} {k}': [s for s in ip_sockets(pid) if s[1] != '127.0.0.1']
                   for n, node in (('plant', plant), ('controller', controller))
                   for k, pid in _processes(node.proc.pid).items()}
    finally:
        faults = sorted({w & FAULTS for w in words if w & FAULTS})
        pathlib.Path(out).write_text(json.dumps({'moves': moves, 'faults': faults,
                                                 'beyond_loopback': sockets}))
        client.destroy_node()
        rclpy.try_shutdown()
        for node in (controller, plant):
            node.stop()


def _processes(bridge: int) -> dict[str, int]:
    """The processes of a node the user started: its bridge (`bridge`), the loop and the
    relay (its children, by their command lines)."""
    out = {'bridge': bridge}
    kids = pathlib.Path(f'/proc/{bridge}/task/{bridge}/children').read_text().split()
    for pid in kids:
        cmd = pathlib.Path(f'/proc/{pid}/cmdline').read_bytes().split(b'\0')
        out['relay' if b'relay' in cmd else 'loop'] = int(pid)
    return out


# -- the laptop ----------------------------------------------------------------------------------
def laptop(out: str, *phases: str) -> None:
    rclpy.init()
    tools = Laptop()
    found: dict = {}
    try:
        for phase in phases:
            name, _, arg = phase.partition(':')
            key = name if name not in found else f'{name}_2'
            n0, j0 = len(tools.loop), len(tools.joints)
            found[key] = getattr(tools, name)(arg)
            found[key]['loop'] = [{k: d.get(k) for k in ('rate_hz', 'overruns_total')}
                                  for d in tools.loop[n0:]]
            found[key]['gaps'] = gaps(tools.joints[j0:])
            pathlib.Path(f'{out}.{key}').write_text(json.dumps(found[key]))
    finally:
        pathlib.Path(out).write_text(json.dumps(found))
        tools.destroy_node()
        rclpy.try_shutdown()


def gaps(arrivals: list[float], longer: float = 0.5) -> list[tuple[float, float]]:
    """(start, end) wall-clock times of the pauses over `longer` s between arrivals."""
    return [(a, b) for a, b in zip(arrivals, arrivals[1:]) if b - a > longer]


class Laptop(Node):
    """What `ros2 param`, `ros2 topic echo`, `ros2 topic pub` do, by rclpy."""

    def __init__(self):
        super().__init__('laptop_tools')
        self.params = AsyncParameterClient(self, '/controller')
        self.joints: list[float] = []         # arrival (wall clock) of each joint_states
        self.words: list[int] = []
        self.sources: list = []
        self.create_subscription(UInt32, md.status_topic('x'),
                                 lambda m: self.words.append(m.data), 10)
        self.loop: list[dict] = []            # the controller's servo loop status, each second
        self.create_subscription(DiagnosticArray, md.DIAGNOSTICS, self._on_diagnostics, 10)

    def _on_diagnostics(self, msg) -> None:
        for st in msg.status:
            if st.name.endswith(' source'):
                self.sources.append((st.name, st.level[0], [kv.key for kv in st.values]))
            elif st.name.endswith('servo loop'):
                self.loop.append({kv.key: kv.value for kv in st.values})

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(self, timeout_sec=0.05)

    def wait(self, future, timeout: float = 10.0):
        rclpy.spin_until_future_complete(self, future, timeout_sec=timeout)
        return future.result()

    # -- phases ----------------------------------------------------------------------------
    def discover(self, _arg) -> dict:
        t0 = time.monotonic()
        ok = self.params.wait_for_services(30.0)
        return {'services': ok, 'seconds': round(time.monotonic() - t0, 2)}

    def params_round(self, _arg) -> dict:
        """get, set (and back), dump (every parameter's value), load (the dump's x.*)."""
        kp = self.wait(self.params.get_parameters(['x.kp'])).values[0].double_value
        set_ok = self.wait(self.params.set_parameters(
            [Parameter('x.kp', value=kp * 1.01)])).results[0].successful
        now = self.wait(self.params.get_parameters(['x.kp'])).values[0].double_value
        self.wait(self.params.set_parameters([Parameter('x.kp', value=kp)]))
        names = self.wait(self.params.list_parameters()).result.names
        values = self.wait(self.params.get_parameters(names)).values
        dump = {n: parameter_value_to_python(v) for n, v in zip(names, values)}
        mine = [Parameter(n, value=v) for n, v in dump.items() if n.startswith('x.')]
        loaded = self.wait(self.params.set_parameters(mine)).results
        return {'kp': kp, 'set': set_ok, 'kp_after_set': now, 'dumped': len(dump),
                'loaded': len(mine), 'load_refused': [
                    (p.name, r.reason) for p, r in zip(mine, loaded) if not r.successful]}

    def echo(self, seconds: str) -> dict:
        """`ros2 topic echo /joint_states` for `seconds` (a reader of its own, as each echo
        is: none is left to load the relays while the recording runs)."""
        n0, w0 = len(self.joints), len(self.words)
        sub = self.create_subscription(JointState, md.JOINT_STATES,
                                       lambda m: self.joints.append(time.time()), 10)
        self.spin_until(lambda: len(self.joints) > n0, 10.0)
        n0, t0 = len(self.joints), time.time()
        self.spin_for(float(seconds))
        self.destroy_subscription(sub)
        return {'joint_states': len(self.joints) - n0, 'status_words': len(self.words) - w0,
                'first': t0}

    def spin_until(self, done, timeout: float) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end and not done():
            rclpy.spin_once(self, timeout_sec=0.05)

    def listen(self, seconds: str) -> dict:
        """Tools attached for `seconds` while the test takes the link down and up: the
        pauses of joint_states (the phase's `gaps`) say when they stopped and came again."""
        return self.echo(seconds)

    def record(self, seconds: str) -> dict:
        bag = pathlib.Path(os.environ['TWO_HOSTS_DIR']) / 'laptop_bag'
        proc = subprocess.Popen([sys.executable, '-m', 'motion_ctrl.tools.record', '-o',
                                 str(bag), *RECORDED], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
        self.spin_for(float(seconds))
        proc.send_signal(2)
        text = proc.communicate(timeout=30)[0]
        return {'rc': proc.returncode, 'output': text[-3000:], 'bag': str(bag)}

    def commander(self, seconds: str) -> dict:
        """10 V on `command` and a far `encoders` reading, from this host."""
        cmd = self.create_publisher(JointState, md.COMMAND, md.SERVO_QOS)
        enc = self.create_publisher(JointState, md.ENCODERS, md.SERVO_QOS)
        self.spin_for(2.0)                 # (matched, and seen by the relays' look)
        s0, end = len(self.sources), time.monotonic() + float(seconds)
        while time.monotonic() < end:
            stamp = self.get_clock().now().to_msg()
            cmd.publish(md.joint_state(stamp, ['x'], effort=[10.0]))
            enc.publish(md.joint_state(stamp, ['x_motor', 'x_load'], [1e6, 1e6]))
            self.spin_for(0.01)
        self.spin_for(2.5)                     # (the statuses of the last second)
        return {'sources': self.sources[s0:],
                'matched': [cmd.get_subscription_count(), enc.get_subscription_count()]}


if __name__ == '__main__':
    sys.path[:0] = [str(ROOT / 'test'), str(ROOT)]
    if sys.argv[1] == 'controller_pc':
        controller_pc(*sys.argv[2:])
    else:
        laptop(*sys.argv[2:])
