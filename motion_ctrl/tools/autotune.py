"""`autotune`: gains and a notch for an axis from its measured response, with the margins they
give on the measured open loop; on request applied and verified with real moves (the ROS shell
of motion_ctrl/analysis/autotune.py; Kollmorgen WorkBench's Performance Servo Tuner).

1. The response: an `identify` output folder (`--from DIR`: identify.yaml, the fitted two-mass
   model and friction, and response.csv, the measured points), or, without --from, `identify`
   is run on the axis first (into OUT/identify).
2. The proposal for `--preset` stiff / medium / soft and the axis's `feedback` (dual or motor):
   kp, ki, kd, kvff, kaff, friction_ff and, where the resonance limits the loop, the Ixx36–39
   notch; printed with its margins and bandwidth beside the controller's current registers;
   written as `ros2 param load` YAML (autotune.yaml), with a Bode plot of both open loops,
   margins marked (open_loop.png) and report.md. With them the rest settings
   (analysis.rest): the anti-hunting window, the fine window, the breakaway aid and the
   settling time, from the slip identify's friction predicts, and the accuracy they promise.
3. `--apply`: the demo's moves (1 in, +2 in, back to +1 in: the headline move after a reversal)
   with the current registers; the gains loaded with each rest candidate in turn and short
   test moves, until one brings every test move to rest (rest.search); the proposal loaded
   (load_parameter_file_atomically, as `ros2 param load`), the demo's moves again. Each move
   is watched `--rest` s after MOTION_DONE: settled only if neither the slide's reading nor the
   output turns back (a move that never settles: its limit cycle, period and amplitude). A
   before/after table of settle time (end of the profile to MOTION_DONE), overshoot, final
   error, the output's peak-to-peak at rest and the rest, from the controller's own
   joint_states and status (never plant_states), steps.png and verification.yaml.

With --from and neither --apply nor --spawn it needs no ROS: the registers it compares with are
the register table's defaults (or `--current FILE`, a `ros2 param load` YAML).
"""
from __future__ import annotations

import argparse
import math
import pathlib
import sys

import numpy as np

from motion_ctrl.analysis import autotune as at
from motion_ctrl.analysis import rest
from motion_ctrl.core.registers import INCH, axis_defaults
from motion_ctrl.procedures.session import session_arguments

MOVES = (('0 -> 1 in (after the return to 0)', INCH), ('+2 in', 2 * INCH),
         ('back to +1 in (reversal)', INCH))
READ = ('feedback', 'load_counts_per_m') + at.GAIN_REGISTERS + rest.REST_REGISTERS
RETURN = 'return to 0 (before the moves)'


class AutotuneError(RuntimeError):
    pass


class MoveRecorder:
    """The controller's joint_states (raw, decoded after) while a move is measured, each with
    how many status changes had arrived before it: the status events get the samples' stamps
    (the controller's clock: sim time in lockstep). Times are counted in samples (one per servo
    tick at `rate`), so a move is measured alike in real time and in lockstep."""

    def __init__(self, client, axis: str, rate: float, coulomb: float = 0.0):
        from sensor_msgs.msg import JointState
        from diagnostic_msgs.msg import DiagnosticArray
        import msg_defs as md
        self.client, self.axis, self.rate, self.coulomb = client, axis, rate, coulomb
        self._type = JointState
        self._raw: list = []
        self._on = False
        self.hunting = ''        # the controller's /diagnostics message while it reports hunting
        client.create_subscription(JointState, md.JOINT_STATES, self._on_joint,
                                   md.SERVO_READ_QOS, raw=True)
        client.create_subscription(DiagnosticArray, md.DIAGNOSTICS, self._on_diagnostics, 10)

    def _on_diagnostics(self, msg) -> None:
        for st in msg.status:
            if st.hardware_id == self.axis and st.name.endswith(f'axis {self.axis}'):
                values = {kv.key: kv.value for kv in st.values}
                if values.get('hunting') == 'True':
                    self.hunting = st.message

    def _on_joint(self, data: bytes) -> None:
        if self._on:
            self._raw.append((data, len(self.client.status_log[self.axis])))

    def move(self, label: str, target: float, counts_per_m: float, timeout: float,
             rest_s: float, tolerate: bool = False) -> at.MoveResult:
        """One move, measured: until MOTION_DONE and `rest_s` after it, or `timeout` after the
        command without MOTION_DONE (the controller's clock). tolerate: a move without
        MOTION_DONE (the axis hunts around the target) is measured as it is, settle inf and its
        limit cycle, instead of ending the run."""
        from rclpy.serialization import deserialize_message
        from msg_defs.status import Status
        import msg_defs as md
        from motion_ctrl.ros.client import FAULTS
        client, name = self.client, self.axis
        self._raw.clear()
        self._on = True
        self.hunting = ''
        mark = len(client.status_log[name])
        try:
            if not client.spin_until(lambda: len(self._raw) > 0, 5.0):
                raise AutotuneError('no joint_states from the controller')
            n0 = len(self._raw)
            budget = n0 + int(round(timeout * self.rate))

            def faulted():
                return any(w & FAULTS for _, w in client.status_log[name][mark:])
            client.pub_target.publish(md.joint_state(client.get_clock().now().to_msg(), [name],
                                                     [target]))
            # (a wall-clock guard only: the budget is the controller's samples)
            client.spin_until(lambda: client.move_done(name, mark) or faulted()
                              or len(self._raw) >= budget, 30.0 + 30.0 * timeout)
            done = client.move_done(name, mark) and not faulted()
            if not done and not tolerate:
                word = client.status[name] or 0
                raise AutotuneError(f'move to {target:.4f} m: no MOTION_DONE within {timeout:g} s '
                                    f'(status {Status(word)!r})')
            if done:
                n1 = len(self._raw)
                if not client.spin_until(lambda: len(self._raw) >= n1 + rest_s * self.rate,
                                         30.0 + 30.0 * rest_s):
                    raise AutotuneError('joint_states stopped after the move')
        finally:
            self._on = False
        log = client.status_log[name]
        words = [w for _, w in log]
        # the move: the first word after the target without MOTION_DONE, then AT_TARGET, then
        # MOTION_DONE
        i0 = next((i for i in range(mark, len(words)) if not words[i] & Status.MOTION_DONE),
                  None)
        if i0 is None:
            if not tolerate:
                raise AutotuneError(f'move to {target:.4f} m: MOTION_DONE never cleared')
            i0 = len(words)          # no status change at all: not ended, measured as it is
        i_end = next((i for i in range(i0, len(words)) if words[i] & Status.AT_TARGET), None)
        i_done = next((i for i in range(i_end if i_end is not None else i0, len(words))
                       if words[i] & Status.MOTION_DONE), None)
        if any(words[i] & FAULTS for i in range(i0, len(words))):
            raise AutotuneError(f'move to {target:.4f} m faulted ({Status(words[-1])!r})')
        t, pos, eff, seen = [], [], [], []
        for data, count in self._raw:
            msg = deserialize_message(data, self._type)
            try:
                k = list(msg.name).index(name)
            except ValueError:
                continue
            t.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
            pos.append(msg.position[k])
            eff.append(msg.effort[k] if len(msg.effort) > k else 0.0)
            seen.append(count)
        seen_a = np.asarray(seen)

        def stamp(index):
            """The stamp of the first sample that arrived after status event `index`."""
            if index is None:
                return None
            after = np.flatnonzero(seen_a > index)
            return t[int(after[0])] if after.size else None
        t_end, t_done = stamp(i_end), stamp(i_done)
        r = at.move_result(label, target, pos[0], t, pos, eff, t_end, t_done, counts_per_m,
                           self.coulomb)
        if client.wants_truth and client.truth_since(t[-1]):
            # the simulated plant's own slide (--spawn), beside what the controller read
            r.true_error = (client.truth[md.load_joint(name)] - target) * counts_per_m
        return r


def run_moves(rec: MoveRecorder, axis, counts_per_m: float, timeout: float, rest_s: float,
              log=print, tolerate: bool = False, home: bool = True) -> list:
    """Back to 0, then the demo's three moves, each watched `rest_s` at rest; returns their
    MoveResults. tolerate (the gains before): a move that does not come to rest is measured
    (its limit cycle) and ends the series there; the return to 0 as well, and then it is the
    series' only result."""
    out = []
    if tolerate:
        r = rec.move(RETURN, 0.0, counts_per_m, timeout, rest_s, tolerate)
        log(f'autotune:   {RETURN}: {r.rest.describe()}')
        if rec.hunting:
            log(f"autotune:   the controller's /diagnostics: {rec.hunting}")
        if not r.settled:
            log('autotune:   (the axis does not come to rest with these registers: the rest '
                'of their moves is skipped)')
            return [r]
    elif home:
        axis.move(0.0, timeout)
    for label, target in MOVES:
        r = rec.move(label, target, counts_per_m, timeout, rest_s, tolerate)
        settle = f'{r.settle_ms:.0f} ms' if math.isfinite(r.settle_ms) else \
            f'no MOTION_DONE within {timeout:g} s'
        log(f'autotune:   {label}: settle {settle}, overshoot {r.overshoot:.2f}, '
            f'final error {r.final_error:+.2f} counts, output p-p {r.output_pp:.3f} V; '
            f'{r.rest.describe()}')
        out.append(r)
        if rec.hunting:
            log(f"autotune:   the controller's /diagnostics: {rec.hunting}")
        if not r.settled and tolerate:
            log('autotune:   (the axis does not come to rest with these registers: the rest '
                'of their moves is skipped)')
            break
    return out


def test_moves(rec: MoveRecorder, axis, registers, counts_per_m: float):
    """rest.search's trial over ROS: the candidate's `registers(candidate)` set, then
    rest.TEST_MOVES, each until MOTION_DONE (rest.TEST_TIMEOUT) and rest.TEST_REST at rest; a
    trial fails at the first move that hunts (rest.Judgement.hunts) and ends there, unless
    `every` (then all are made and those that hunt counted)."""
    def trial(c: rest.Candidate, every: bool = False) -> rest.Trial:
        axis.set(registers(c))
        settles: list[float] = []
        out = rest.Trial(c, True)
        for d in rest.TEST_MOVES:
            r = rec.move(f'test {d:+g} counts', d / counts_per_m, counts_per_m,
                         rest.TEST_TIMEOUT, rest.TEST_REST, tolerate=True)
            out.moves += 1
            if not r.rest.hunts:
                if math.isfinite(r.settle_ms):
                    settles.append(r.settle_ms)
                continue
            out.hunted += 1
            if out.ok:
                out.ok, out.reason, out.failed = False, (f'test move to {d:+g} counts: '
                                                        f'{r.rest.describe()}'), r
            if not every:
                break
        out.settle_ms = settles
        return out
    return trial


def read_current(path, axis: str) -> dict:
    """The axis's registers from a `ros2 param load` YAML file (`<axis>.<register>` keys) over
    the register table's defaults: {register: value}."""
    import yaml
    try:
        doc = yaml.safe_load(pathlib.Path(path).read_text())
        params = next(iter(doc.values()))['ros__parameters']
        mine = {k.split('.', 1)[1]: v for k, v in params.items()
                if k.startswith(f'{axis}.')}
    except (OSError, yaml.YAMLError, AttributeError, KeyError, StopIteration, TypeError) as e:
        raise AutotuneError(f'--current {path}: not a ros2 param load file ({e})') from None
    if not mine:
        raise AutotuneError(f'--current {path}: no registers of axis {axis} ({axis}.kp, ...)')
    return axis_defaults() | mine


class Tuning:
    """What autotune proposes for an axis: the gains (analysis.autotune.propose), the rest
    settings (analysis.rest: the plan from identify's friction, and once tried on the axis the
    candidate its test moves chose), written as one ros2 param load file."""

    def __init__(self, response: at.AxisResponse, current: dict, args, log=print):
        self.response, self.current, self.args, self.log = response, current, args, log
        self.feedback = args.feedback or current.get('feedback', 'dual')
        try:
            self.before = at.evaluate(response, current, self.feedback)
            self.prop = at.propose(response, args.preset, self.feedback,
                                   notch={'auto': None, 'on': True, 'off': False}[args.notch])
        except ValueError as e:
            raise AutotuneError(str(e)) from None
        self.cpm = float(current['load_counts_per_m'])
        slip = response.slip()
        self.plan = rest.plan(slip, self.cpm, self.feedback)
        self.rest = self.plan.candidates[0]          # until test moves chose (choose)
        self.tried = False
        self.trials: list = []
        self.control: rest.Trial | None = None      # the rest settings as shipped, tried
        self.yaml_path = pathlib.Path()
        self.text = ''

    def rest_registers(self, c: rest.Candidate) -> dict:
        return c.registers(self.current, self.cpm, self.prop.registers['friction_ff'],
                           self.response.model.antiresonance_hz)

    def registers(self, c: rest.Candidate | None = None) -> dict:
        """Gains and rest settings (of `c`, default the one proposed)."""
        return self.prop.registers | self.rest_registers(c or self.rest)

    def rest_text(self) -> list:
        regs = self.rest_registers(self.rest)
        lines = list(self.plan.notes)
        if self.trials:
            for t in self.trials:
                lines.append(f'rest: tried {t.candidate}: {t.describe()}')
        chosen = ('chosen by the test moves' if self.tried else
                  'no test moves needed: the slip is under half a count, or the loop does not '
                  'see the slide' if not self.plan.test else
                  'from the prediction, not tried on the axis (--apply tries it)')
        lines.append(f'rest: proposed {self.rest} ({chosen})')
        lines.append('rest: accuracy: the slide stops within ' + rest.describe_promise(
            regs['window_centre'], regs['fine_position_tolerance'] * self.cpm)
            + self._tighter())
        return lines

    def _tighter(self) -> str:
        w = self.rest.window
        if w == 0.0:
            return ''
        return ('; tighter needs a slide that slips less than the window is wide (less '
                'stiction over its sliding friction, a stiffer screw) or a finer encoder')

    def write(self, out: pathlib.Path) -> pathlib.Path:
        """autotune.yaml, open_loop.png, report.md; the text printed."""
        prop, args = self.prop, self.args
        text = at.format_proposal(prop, self.before) + '\n' + '\n'.join(self.rest_text())
        header = (f'motion_ctrl autotune: preset {prop.preset.name}, feedback {prop.feedback}\n'
                  f'gain margin {prop.evaluation.gain_margin_db:.1f} dB, phase margin '
                  f'{prop.evaluation.phase_margin_deg:.1f}° on the measured open loop (one tick '
                  f'of latency), crossover {prop.evaluation.crossover_hz or 0:.1f} Hz, bandwidth '
                  f'{prop.evaluation.bandwidth_hz:.1f} Hz\n'
                  f'rest: {self.rest}\n'
                  f'load with: ros2 param load /controller <this file>')
        yaml_path = out / 'autotune.yaml'
        text_yaml = at.params_yaml(self.registers(), args.axis, comment=header)
        if args.feedback and args.feedback != self.current.get('feedback'):
            # tuned for another loop than the axis runs: the file switches it (with the gains,
            # at once: load_parameter_file_atomically)
            text_yaml += f'    {args.axis}.feedback: {args.feedback}\n'
        yaml_path.write_text(text_yaml)
        png = out / 'open_loop.png'
        at.plot_open_loop(png, self.response, [('current', self.before),
                                               (f'{prop.preset.name} (proposed)',
                                                prop.evaluation)],
                          title=f'axis {args.axis}, feedback {prop.feedback}: open loop L '
                                '(line: model, markers: measured points; one tick of latency)')
        (out / 'report.md').write_text(text + '\n')
        self.text = text
        return yaml_path


def propose_and_write(response: at.AxisResponse, current: dict, args, out: pathlib.Path,
                      log=print) -> Tuning:
    """The proposal, printed and written (autotune.yaml, open_loop.png, report.md)."""
    tuning = Tuning(response, current, args, log)
    yaml_path = tuning.write(out)
    log(tuning.text)
    if args.feedback and args.feedback != current.get('feedback'):
        log(f'autotune: the file sets {args.axis}.feedback: {args.feedback} (now '
            f'{current.get("feedback")})')
    log(f'autotune: wrote {yaml_path}, {out / "open_loop.png"}, {out / "report.md"}')
    if response.motor is None:
        log('autotune: note: no response.csv beside identify.yaml: the margins are the '
            "model's only (identify writes the measured points since autotune)")
    tuning.yaml_path = yaml_path
    return tuning


def autotune_ros(client, axis, args, out: pathlib.Path, log=print) -> dict:
    from motion_ctrl.ros.client import FAULTS
    from msg_defs.status import Status
    from motion_ctrl.procedures.session import SessionError
    from rclpy.parameter import parameter_value_to_python
    word = client.status[args.axis] or 0
    if word & FAULTS or not word & Status.ENABLED:
        raise AutotuneError(f'axis {args.axis} is not ready ({Status(word)!r}): reset and '
                            f'enable it first ({args.axis}/reset, {args.axis}/enable)')
    current = axis.get(*READ)
    rate_value = client.answer(lambda: axis.params.get_parameters(['servo_rate'])).values[0]
    rate = float(parameter_value_to_python(rate_value))  # type: ignore[arg-type]
    # (subscribed now, before identify: a reader joining later holds the controller up,
    # doc/design_notes.md)
    rec = MoveRecorder(client, args.axis, rate) if args.apply else None
    if args.source is None:
        from motion_ctrl.tools import identify as tid
        iargs = tid.parser().parse_args(['--axis', args.axis])
        iargs.servo_rate = rate
        idir = out / 'identify'
        idir.mkdir(exist_ok=True)
        log(f'autotune: measuring the axis first (identify into {idir})')
        try:
            tid.identify(axis, iargs, idir, log=log)
        except tid.IdentifyError as e:
            raise AutotuneError(f'identify: {e}') from None
        args.source = idir
    response = _read(args.source)
    tuning = propose_and_write(response, current, args, out, log)
    result = dict(proposal=tuning.prop, before=tuning.before, tuning=tuning)
    if not args.apply:
        return result
    cpm = tuning.cpm
    assert rec is not None
    rec.coulomb = tuning.prop.registers['friction_ff']
    saved = {k: current[k] for k in at.GAIN_REGISTERS + rest.REST_REGISTERS}
    changed = False
    try:
        log('autotune: verification, current registers')
        runs = {'before': run_moves(rec, axis, cpm, args.move_timeout, args.rest, log,
                                    tolerate=True)}
        changed = True
        if tuning.plan.test:
            log('autotune: the rest settings, tried with short test moves (rest.search)')
            trial = test_moves(rec, axis, tuning.registers, cpm)
            if tuning.plan.control is not None:
                t = trial(tuning.plan.control, every=True)
                tuning.control = t
                log(f'autotune: (for the record) {t.candidate}, as the gains alone would run: '
                    + ('no test move hunted' if t.ok else
                       f'{t.hunted} of {t.moves} test moves hunted; the first, {t.reason}'))
            chosen, made = rest.search(tuning.plan.candidates, trial,
                                       log=lambda x: log(f'autotune: {x}'))
            tuning.trials, tuning.tried = made, True
            if chosen is None:
                log('autotune: no rest settings tried held the slide at rest: the widest is '
                    'proposed; the verification below shows how it does')
                chosen = tuning.plan.candidates[-1]
            tuning.rest = chosen
        yaml_path = tuning.write(out)
        log('\n'.join(tuning.rest_text()))
        axis.load_file(yaml_path)
        log(f'autotune: loaded {yaml_path}; verification, proposed registers')
        runs['after'] = run_moves(rec, axis, cpm, args.move_timeout, args.rest, log)
        if tuning.control is not None and tuning.control.failed is not None:
            # what the gains alone (the rest as shipped) did on the slide: the test move that
            # did not come to rest
            runs = {'before': runs['before'], 'gains alone': [tuning.control.failed],
                    'after': runs['after']}
    except (AutotuneError, SessionError) as e:
        if changed:
            log(f'autotune: {e}; putting the registers back')
            axis.set(saved)
        raise
    if args.restore:
        axis.set(saved)
        log('autotune: registers put back (--restore)')
    evs = {'before': tuning.before, 'gains alone': tuning.prop.evaluation,
           'after': tuning.prop.evaluation}
    table = at.format_verification(runs, evs)
    log(table)
    png = out / 'steps.png'
    at.plot_steps(png, runs, title=f'axis {args.axis}: the demo\'s moves, before and after '
                  f'autotune --preset {tuning.prop.preset.name} (controller joint_states)')
    with open(out / 'report.md', 'a') as f:
        f.write('\n' + table + '\n')
    import yaml
    summary = {name: dict(
        gain_margin_db=float(evs[name].gain_margin_db),
        phase_margin_deg=float(evs[name].phase_margin_deg),
        crossover_hz=float(evs[name].crossover_hz or 0.0),
        bandwidth_hz=float(evs[name].bandwidth_hz),
        moves=[move_summary(m) for m in moves])
        for name, moves in runs.items()}
    summary['rest'] = dict(
        slip_counts=tuning.plan.slip_counts, proposed=str(tuning.rest),
        window_counts=tuning.rest.window, aid_share=tuning.rest.aid_share,
        promise=rest.describe_promise(tuning.registers()['window_centre'],
                                      tuning.registers()['fine_position_tolerance'] * cpm),
        control=None if tuning.control is None else dict(
            tried=str(tuning.control.candidate), at_rest=tuning.control.ok,
            reason=tuning.control.reason, moves=tuning.control.moves,
            hunted=tuning.control.hunted),
        trials=[dict(tried=str(t.candidate), at_rest=t.ok, reason=t.reason,
                     settle_ms=[float(x) for x in t.settle_ms]) for t in tuning.trials])
    (out / 'verification.yaml').write_text(yaml.safe_dump(summary, sort_keys=False,
                                                          allow_unicode=True))
    log(f'autotune: wrote {png}')
    result['runs'] = runs
    unsettled = [m.label for m in runs['after'] if not m.settled]
    result['at_rest'] = not unsettled
    if unsettled and not args.restore:
        axis.set(saved)
        log(f'autotune: the proposal did not bring every move to rest ({", ".join(unsettled)}):'
            ' registers put back')
    return result


def move_summary(m: at.MoveResult) -> dict:
    j = m.rest
    return dict(move=m.label, target=m.target, settle_ms=float(m.settle_ms),
                overshoot_counts=float(m.overshoot), final_error_counts=float(m.final_error),
                output_pp_v=float(m.output_pp), at_rest=bool(j.settled),
                rest=j.describe(), moved_counts=float(j.moved), output_turns=int(j.output_turns),
                limit_cycle_period_s=None if j.done or not math.isfinite(j.period)
                else float(j.period),
                limit_cycle_amplitude_counts=None if j.done else float(j.amplitude),
                true_final_error_counts=None if m.true_error is None else float(m.true_error))


def _read(source) -> at.AxisResponse:
    try:
        return at.read_identify(source)
    except ValueError as e:
        raise AutotuneError(str(e)) from None


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog='autotune', description='Propose gains (kp, ki, kd, kvff, kaff, friction_ff) and '
        'a notch for a preset from the measured response, with the margins on the measured '
        'open loop; write ros2 param load YAML and a Bode plot; --apply loads and verifies it '
        'with real moves.')
    ap.add_argument('--axis', default='x')
    ap.add_argument('--from', dest='source', default=None, metavar='DIR',
                    help='identify output folder (identify.yaml, response.csv); without it '
                    'identify is run on the axis first')
    ap.add_argument('--preset', choices=sorted(at.PRESETS), default='stiff',
                    help='stiff, medium: 8 dB / 45° (crossover up to 0.5 / 0.3 of the '
                    'anti-resonance); soft: 10 dB / 55° (0.2). Default stiff')
    ap.add_argument('--feedback', choices=('dual', 'motor', 'sampled'), default=None,
                    help='loop to tune (default: the controller\'s feedback register, dual '
                    'offline)')
    ap.add_argument('--notch', choices=('auto', 'on', 'off'), default='auto',
                    help='auto (default): only where the resonance limits the loop and a '
                    'notch buys 10 %% more ki (doc/autotune.md: the rule)')
    ap.add_argument('--current', default=None, metavar='FILE',
                    help='offline: the registers to compare with, as ros2 param load YAML '
                    '(default: the register table\'s defaults)')
    ap.add_argument('--apply', action='store_true',
                    help='load the proposal into the controller and verify it with the demo\'s '
                    'moves before and after')
    ap.add_argument('--restore', action='store_true',
                    help='with --apply: put the previous registers back after the verification')
    ap.add_argument('--move-timeout', type=float, default=10.0,
                    help='s of the controller\'s clock a verification move may take to '
                    'MOTION_DONE (default 10)')
    ap.add_argument('--rest', type=float, default=2.0,
                    help='s each verification move is watched at rest after MOTION_DONE: '
                    'settled only if neither the slide\'s reading nor the output turns back '
                    '(default 2)')
    session_arguments(ap, 'autotune', 'x.screw_stiffness:=1.0e6')
    return ap


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if args.lockstep and not args.spawn:
        print('autotune: --lockstep needs --spawn', file=sys.stderr)
        return 2
    if args.restore and not args.apply:
        print('autotune: --restore needs --apply', file=sys.stderr)
        return 2
    for name in ('move_timeout', 'rest'):
        if not (math.isfinite(getattr(args, name)) and getattr(args, name) > 0):
            print(f'autotune: --{name.replace("_", "-")} must be > 0 s', file=sys.stderr)
            return 2
    from motion_ctrl.procedures.session import SessionError, axis_session
    offline = args.source is not None and not (args.apply or args.spawn)
    try:
        if offline:
            import datetime
            out = pathlib.Path(args.out or datetime.datetime.now().strftime(
                'out/autotune-%Y%m%d-%H%M%S'))
            out.mkdir(parents=True, exist_ok=True)
            current = read_current(args.current, args.axis) if args.current else axis_defaults()
            tuning = propose_and_write(_read(args.source), current, args, out)
            return 0 if tuning.prop.ok else 1
        if args.current:
            print('autotune: --current is for offline use (the controller\'s registers are '
                  'read when it is there)', file=sys.stderr)
            return 2
        with axis_session(args, 'autotune', services=args.source is None,
                          truth=args.spawn) as (client, axis, out):
            result = autotune_ros(client, axis, args, out)
    except (AutotuneError, SessionError) as e:
        print(f'autotune: {e}', file=sys.stderr)
        return 1
    return 0 if result['proposal'].ok and result.get('at_rest', True) else 1


if __name__ == '__main__':
    sys.exit(main())
