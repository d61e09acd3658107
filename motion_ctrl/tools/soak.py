"""The servo loop while people use ROS on it: 1-inch moves back and forth over DDS, with ROS
participants joining and leaving (`motion_ctrl.ros.visitor`, like `ros2 param get` or `ros2 topic
echo`), optionally a recorder started and stopped and a busy CPU loop beside it.

`scripts/soak [--minutes 10] [--interval 5] [--busy 1] [--realtime-priority 30]` runs it with
the shipped parameters and prints the count of moves, of faults (FEEDBACK_FAULT,
FOLLOWING_ERROR_FATAL), of moves that end within 1 linear count on the true slide, of moves
whose MOTION_DONE the client saw only after 5 s without a fault (counted apart: the loop was
done, a loaded bridge's copies were not), and the RSS
of both nodes' processes (the loop on the servo bus, the bridge) after WARM_UP_MOVES and at the
end. The churn test (test/ros/test_ros_churn.py) drives the same `Soak` with 20 visitors and a
recorder. `scripts/soak --floods` instead floods the loop with targets and oversized inputs and
prints its rate before and during each (motion_ctrl.procedures.floods).
"""
from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import threading
import time

import rclpy

from msg_defs.status import Status
from motion_ctrl.core.registers import INCH, LOAD_COUNTS_PER_M
from motion_ctrl.procedures import floods
from motion_ctrl.ros import ros_env
from motion_ctrl.ros.client import FAULTS, SlideClient

LATE_WAIT = 25.0     # s more for a MOTION_DONE not seen in 5 s (a bridge's copies late)
BUSY_LOOP = 'while True: pass'


WARM_UP_MOVES = 4


def rss_kb(pid: int) -> int:
    """Resident set size of a process [kB] (Linux)."""
    with open(f'/proc/{pid}/status') as f:
        return next(int(line.split()[1]) for line in f if line.startswith('VmRSS:'))


class Visitors:
    """Starts `python -m motion_ctrl.ros.visitor` every `interval` seconds in a thread, at most
    `parallel` alive at once, until `count` have run or stop() is called."""

    def __init__(self, interval: float, count: int | None = None, parallel: int = 1,
                 env=None):
        self.interval, self.count, self.parallel, self.env = interval, count, parallel, env
        self.started = self.finished = 0
        self.failed: list[str] = []
        self.spans: list[tuple[float, float]] = []     # (start, end) epoch s of each visitor
        self._born: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> 'Visitors':
        self._thread.start()
        return self

    def done(self) -> bool:
        return not self._thread.is_alive()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        alive: list[subprocess.Popen] = []
        while not self._stop.is_set() and (self.count is None or self.started < self.count):
            alive = [p for p in alive if not self._reap(p)]
            if len(alive) < self.parallel:
                p = subprocess.Popen(
                    [sys.executable, '-m', 'motion_ctrl.ros.visitor'], env=self.env,
                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
                self._born[p.pid] = time.time()
                alive.append(p)
                self.started += 1
            self._stop.wait(self.interval)
        for p in alive:
            p.wait()
            self._reap(p)

    def _reap(self, p: subprocess.Popen) -> bool:
        if p.poll() is None:
            return False
        out = p.stdout.read() if p.stdout else ''
        self.spans.append((self._born.pop(p.pid, 0.0), time.time()))
        self.finished += 1
        if p.returncode != 0:
            last = out.strip().splitlines()[-3:] if out.strip() else []
            self.failed.append(' | '.join([f'exit {p.returncode}', *last]))
        return True


class Soak:
    """Moves `axis` between 0 and `distance` through `client` (a SlideClient with services)
    and keeps the score: every move's result and final error on the true slide."""

    def __init__(self, client, axis: str = 'x', distance: float = INCH):
        self.client, self.axis, self.distance = client, axis, distance
        self.moves = 0
        self.within_1_count = 0
        self.faults: list[str] = []     # status words of moves that ended in a fault
        self.errors: list[float] = []   # final error of every move [linear counts]
        self.late: list[float] = []     # s from target to a MOTION_DONE seen after 5 s
        self.target = 0.0

    def move(self) -> None:
        c = self.client
        self.target = self.distance if self.target == 0.0 else 0.0
        mark, t0 = len(c.status_log[self.axis]), time.monotonic()
        took = c.move({self.axis: self.target}, timeout=5.0)
        self.moves += 1
        if took is None:
            # Not seen to end in 5 s: if no fault came, the loop may be done and its status
            # words still on their way through a loaded machine's bridge (doc/architecture.md,
            # the servo bus). Wait for them and count the move as seen late, apart from the faults.
            took = c.wait_moves({self.axis: mark}, t0, LATE_WAIT)
            if took is not None:
                self.late.append(took)
        word = c.status[self.axis] or 0
        if took is None or word & FAULTS:
            self.faults.append(repr(Status(word)))
            try:
                c.call('reset')
                c.call('enable', True)
            except TimeoutError as e:       # counted; the next move tells whether it recovered
                self.faults.append(f'reset / enable unanswered ({e})')
            c.spin_for(0.2)
            return
        err = (c.load_position(self.axis) - self.target) * LOAD_COUNTS_PER_M
        self.errors.append(err)
        self.within_1_count += abs(err) <= 1.0

    def summary(self) -> str:
        worst = max((abs(e) for e in self.errors), default=float('nan'))
        late = (f', seen late {len(self.late)} (the latest after {max(self.late):.1f} s)'
                if self.late else '')
        return (f'moves {self.moves}, faults {len(self.faults)}, within 1 count '
                f'{self.within_1_count}/{self.moves} (worst {worst:.2f} counts){late}')


class HostSteal(threading.Thread):
    """Time this VM's virtual CPUs were taken by the host (the `steal` column of /proc/stat),
    sampled every 5 ms: a process of any priority stops while its CPU is stolen, so a loop with
    a 20 ms watchdog cannot tell a steal burst from a ROS stall. Each event: (epoch time,
    jiffies stolen since the previous sample)."""

    def __init__(self):
        super().__init__(name='steal', daemon=True)
        self.events: list[tuple[float, int]] = []
        self.running = True

    @staticmethod
    def _steal() -> int:
        with open('/proc/stat') as f:
            return int(f.readline().split()[8])

    def run(self) -> None:
        try:
            prev = self._steal()
        except (OSError, IndexError, ValueError):
            return                                  # not Linux, or no steal accounting
        while self.running:
            time.sleep(0.005)
            now = self._steal()
            if now > prev:
                self.events.append((time.time(), now - prev))
            prev = now

    def near(self, stamp: float, window: float = 0.2) -> bool:
        """Whether the host stole CPU time within `window` s of `stamp` (epoch s)."""
        return any(abs(t - stamp) <= window for t, _ in self.events)


class Beside:
    """What runs beside the nodes in a soak: the busy CPU loops (started here), the visitors
    and the recorder; `stop` ends what still runs."""

    def __init__(self, busy: int):
        self.busy = [subprocess.Popen([sys.executable, '-c', BUSY_LOOP]) for _ in range(busy)]
        self.visitors: Visitors | None = None
        self.recorder: subprocess.Popen | None = None

    def stop(self) -> None:
        if self.visitors is not None and not self.visitors.done():
            self.visitors.stop()
        for b in self.busy:
            b.kill()
        if self.recorder is not None and self.recorder.poll() is None:
            self.recorder.kill()


def fault_stamps(log: str) -> list[float]:
    """Epoch stamps of the FEEDBACK_FAULT and amplifier-fault lines of a node's log
    ('[LEVEL] [1795460490.580106665] [node]: ...')."""
    stamps = []
    for line in log.splitlines():
        if 'FEEDBACK_FAULT' in line or 'amplifier fault' in line:
            try:
                stamps.append(float(line.split('] [', 1)[1].split(']', 1)[0]))
            except (IndexError, ValueError):
                pass
    return stamps


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--minutes', type=float, default=10.0)
    ap.add_argument('--interval', type=float, default=5.0,
                    help='seconds between visitors (new ROS participants)')
    ap.add_argument('--busy', type=int, default=1, help='busy CPU loops beside the nodes')
    ap.add_argument('--servo-bus', default='auto',
                    help='MOTION_CTRL_SERVO_DOMAIN for both nodes: auto (the servo bus, '
                         'doc/architecture.md), a domain id, or off')
    ap.add_argument('--realtime-priority', type=int, default=30,
                    help='realtime_priority of both nodes (0: normal scheduling)')
    ap.add_argument('--visitors', type=int, default=None,
                    help='stop after this many visitors instead of after --minutes')
    ap.add_argument('--parallel', type=int, default=1, help='visitors alive at once, at most')
    ap.add_argument('--record', action='store_true',
                    help='run `record` from the first to the second third of the visitors')
    ap.add_argument('-o', '--out', default=None, help='log directory (default out/soak-<time>)')
    ap.add_argument('--floods', action='store_true',
                    help='instead: floods and oversized inputs, the loop rate before and during '
                         'each (motion_ctrl.procedures.floods, doc/input_limits.md)')
    return ap


def main(argv=None) -> int:
    """Start the slide, soak it (moves while visitors come and go), report; exit 0 when every
    move landed within a count with no fault and no visitor failed."""
    a = parser().parse_args(argv)
    if a.floods:
        return floods.main(a.realtime_priority, a.servo_bus, a.out)
    domain = ros_env.private_domain()
    out = floods.log_dir(a.out, 'soak')
    print(f'soak: {a.minutes:g} min of 1-inch moves, a visitor every {a.interval:g} s, '
          f'{a.busy} busy loop(s), realtime_priority {a.realtime_priority}, servo bus '
          f'{a.servo_bus} (ROS_DOMAIN_ID={domain}, logs in {out})', flush=True)
    nodes = floods.start_nodes(a.realtime_priority, a.servo_bus, out)
    beside = Beside(a.busy)
    rclpy.init()
    client = SlideClient(services=True)
    steal = HostSteal()
    steal.start()
    try:
        if not client.wait_ready(30.0):
            print(f'soak: the nodes did not come up ({client.not_ready()})', file=sys.stderr)
            return 1
        soak, processes, rss = _soak(a, client, nodes, beside, out)
    finally:
        beside.stop()
        client.destroy_node()
        rclpy.try_shutdown()
        rcs = [n.stop() for n in reversed(nodes)]
    visitors, recorder = beside.visitors, beside.recorder
    assert visitors is not None                 # (made by _soak, which returned)
    log = (out / 'controller.log').read_text()
    _report(soak, visitors, processes, rss, rcs, log)
    steal.running = False
    stamps = fault_stamps(log) + fault_stamps((out / 'plant.log').read_text())
    _report_steal(steal, stamps, visitors)
    if a.record:
        print(f'soak: recorder exit code {recorder.returncode if recorder else None}')
    ok = (not soak.faults and soak.within_1_count == soak.moves and not visitors.failed
          and 'FEEDBACK_FAULT' not in log
          and (not a.record or (recorder is not None and recorder.returncode == 0)))
    return 0 if ok else 1


def _soak(a, client, nodes, beside: Beside, out) -> tuple[Soak, list, tuple[list, list]]:
    """The warm-up moves, then moves while the visitors come (and `record` runs, --record),
    until --minutes or --visitors; (the score, the nodes' processes as (what, pid), their RSS
    [kB] after the warm-up and at the end)."""
    soak = Soak(client)
    for _ in range(WARM_UP_MOVES):   # (the streams' histories fill during the first moves)
        soak.move()
    processes = []                   # (what, pid): each node's loop, and its bridge
    for name, n in zip(('plant', 'controller'), nodes):
        loop = n.servo_pid()
        processes.append((f'{name} loop', loop))
        if loop != n.proc.pid:
            processes.append((f'{name} bridge', n.proc.pid))
    rss0 = [rss_kb(pid) for _, pid in processes]
    visitors = beside.visitors = Visitors(a.interval, a.visitors, a.parallel).start()
    end = time.monotonic() + 60.0 * a.minutes
    while (not visitors.done() if a.visitors else time.monotonic() < end):
        soak.move()
        if a.record:
            beside.recorder = _record_between(beside.recorder, visitors, out / 'bag')
    soak.move()
    visitors.stop()
    rss1 = [rss_kb(pid) for _, pid in processes]
    return soak, processes, (rss0, rss1)


def _report(soak: Soak, visitors: Visitors, processes, rss, rcs, log: str) -> None:
    """The score, the visitors, the FEEDBACK_FAULT lines, the RSS growth and the exit codes."""
    print(f'soak: {soak.summary()}; visitors {visitors.finished} '
          f'({len(visitors.failed)} failed); FEEDBACK_FAULT lines in the controller log: '
          f'{log.count("FEEDBACK_FAULT")}')
    for (name, _), r0, r1 in zip(processes, *rss):
        print(f'soak: {name} RSS {r0} kB -> {r1} kB ({100.0 * (r1 - r0) / r0:+.1f} %)')
    print(f'soak: nodes stopped (exit codes {", ".join(map(str, rcs))})')
    for f in soak.faults:
        print(f'soak: fault: {f}')
    for f in visitors.failed:
        print(f'soak: visitor failed: {f}')


def _report_steal(steal: HostSteal, stamps: list[float], visitors: Visitors) -> None:
    """How much CPU the host stole, and how many fault lines came near a steal burst or while
    a visitor was alive."""
    alive = sum(any(a <= s <= b for a, b in visitors.spans) for s in stamps)
    print(f'soak: host steal: {sum(j for _, j in steal.events)} jiffies in '
          f'{len(steal.events)} bursts; of the {len(stamps)} FEEDBACK_FAULT / amplifier-fault '
          f'lines, {sum(steal.near(s) for s in stamps)} within 0.2 s of a steal burst, {alive} '
          'while a visitor was alive')


def _record_between(recorder, visitors: Visitors, bag):
    """`record` started when a third of the visitors came, stopped (SIGINT) at two thirds."""
    count = visitors.count or 0                  # (the soak's visitors run to a count)
    if recorder is None and visitors.started >= count // 3:
        return subprocess.Popen([sys.executable, '-m', 'motion_ctrl.tools.record', '-o', str(bag)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if recorder is not None and recorder.poll() is None \
            and visitors.started >= 2 * count // 3:
        recorder.send_signal(signal.SIGINT)
        recorder.wait(30.0)
    return recorder


if __name__ == '__main__':
    sys.exit(main())
