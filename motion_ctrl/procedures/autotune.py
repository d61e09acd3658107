"""autotune's procedure on a live axis (Kollmorgen WorkBench's Performance Servo Tuner), run by
the `autotune` command: the response (identify's folder, or identify run first:
procedures.identify), the proposal (analysis.autotune.propose, with the rest settings of
analysis.rest) printed and written, and with --apply its verification with real moves: the
demo's moves before, the rest settings tried with short test moves (rest.search), the proposal
loaded, the demo's moves after, each move measured from the controller's own joint_states and
status (never plant_states; MoveRecorder).

rclpy, the message packages and motion_ctrl.ros are imported inside the functions that use
them: autotune's offline mode (--from) starts without them (0.14-0.41 s of imports, measured
2026-11-27) and runs where ROS is blocked (the core tests run it: `scripts/test -m core`).
"""
from __future__ import annotations

import math
import pathlib

import numpy as np
import yaml

import msg_defs as md
from motion_ctrl.analysis import autotune as at
from motion_ctrl.analysis import rest
from motion_ctrl.core.registers import INCH
from motion_ctrl.plotting.open_loop import plot_open_loop
from motion_ctrl.plotting.steps import plot_steps
from motion_ctrl.procedures.identify import (IdentifyError, default_settings, identify,
                                             servo_rate)
from motion_ctrl.procedures.session import SessionError
from msg_defs.status import Status

MOVES = (('0 -> 1 in (after the return to 0)', INCH), ('+2 in', 2 * INCH),
         ('back to +1 in (reversal)', INCH))
READ = ('feedback', 'load_counts_per_m') + at.GAIN_REGISTERS + rest.REST_REGISTERS
RETURN = 'return to 0 (before the moves)'


class AutotuneError(RuntimeError):
    """What stops autotune: the axis not ready, identify's folder unreadable, no gains that
    meet the preset, a verification move that faulted or did not end; the tool prints it and
    exits 1."""


class MoveRecorder:
    """The controller's joint_states (raw, decoded after) while a move is measured, each with
    how many status changes had arrived before it: the status events get the samples' stamps
    (the controller's clock: sim time in lockstep). Times are counted in samples (one per servo
    tick at `rate`), so a move is measured alike in real time and in lockstep."""

    def __init__(self, client, axis: str, rate: float, coulomb: float = 0.0):
        from sensor_msgs.msg import JointState
        from diagnostic_msgs.msg import DiagnosticArray
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
        mark = self._record(target, timeout, rest_s, tolerate)
        i_end, i_done = self._events(mark, target, tolerate)
        t, pos, eff, seen = self._trace()

        def stamp(index):
            """The stamp of the first sample that arrived after status event `index`."""
            if index is None:
                return None
            after = np.flatnonzero(seen > index)
            return t[int(after[0])] if after.size else None
        r = at.move_result(label, target, pos[0], t, pos, eff, stamp(i_end), stamp(i_done),
                           counts_per_m, self.coulomb)
        client = self.client
        if client.wants_truth and client.truth_since(t[-1]):
            # the simulated plant's own slide (--spawn), beside what the controller read
            r.true_error = (client.truth[md.load_joint(self.axis)] - target) * counts_per_m
        return r

    def _record(self, target: float, timeout: float, rest_s: float, tolerate: bool) -> int:
        """The target published and joint_states kept until MOTION_DONE and `rest_s` after it
        (or the budget of `timeout` in samples); returns the status log's length before."""
        from motion_ctrl.ros.client import FAULTS
        client, name = self.client, self.axis
        self._raw.clear()
        self._on = True
        self.hunting = ''
        mark = len(client.status_log[name])
        try:
            if not client.spin_until(lambda: len(self._raw) > 0, 5.0):
                raise AutotuneError('no joint_states from the controller')
            budget = len(self._raw) + int(round(timeout * self.rate))

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
        return mark

    def _events(self, mark: int, target: float, tolerate: bool) -> tuple:
        """The move's status events after `mark`, as indices into the status log: (the end of
        the profile, AT_TARGET; MOTION_DONE), None where not raised: the move is the first word
        without MOTION_DONE, then AT_TARGET, then MOTION_DONE."""
        from motion_ctrl.ros.client import FAULTS
        words = [w for _, w in self.client.status_log[self.axis]]
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
        return i_end, i_done

    def _trace(self) -> tuple:
        """The recorded samples of the axis decoded: stamps [s], positions [m], outputs [V],
        and how many status changes had arrived before each (an array)."""
        from rclpy.serialization import deserialize_message
        t, pos, eff, seen = [], [], [], []
        for data, count in self._raw:
            msg = deserialize_message(data, self._type)
            try:
                k = list(msg.name).index(self.axis)
            except ValueError:
                continue
            t.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
            pos.append(msg.position[k])
            eff.append(msg.effort[k] if len(msg.effort) > k else 0.0)
            seen.append(count)
        return t, pos, eff, np.asarray(seen)


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
        plot_open_loop(png, self.response, [('current', self.before),
                                            (f'{prop.preset.name} (proposed)', prop.evaluation)],
                       title=f'axis {args.axis}, feedback {prop.feedback}: open loop L '
                             '(line: model, markers: measured points; one tick of latency)')
        (out / 'report.md').write_text(text + '\n')
        self.text = text
        return yaml_path


def read_axis(source) -> at.AxisResponse:
    """identify's output folder as analysis.autotune.read_identify reads it; AutotuneError
    naming what is wrong."""
    try:
        return at.read_identify(source)
    except ValueError as e:
        raise AutotuneError(str(e)) from None


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


# ================================================================================================
# on the axis

def autotune_ros(client, axis, args, out: pathlib.Path, log=print) -> dict:
    """autotune on an axis of a ready controller: identify first without --from, the proposal
    against the controller's registers, with --apply its verification (verify). Returns the
    proposal, the evaluation of the registers before and the Tuning; with --apply the moves
    (runs) and whether every move after came to rest (at_rest)."""
    problem = axis.not_ready()
    if problem:
        raise AutotuneError(problem)
    current = axis.get(*READ)
    rate = servo_rate(axis)
    # (subscribed now, before identify: a reader joining later holds the controller up,
    # doc/design_notes.md)
    rec = MoveRecorder(client, args.axis, rate) if args.apply else None
    if args.source is None:
        args.source = measure_first(axis, args.axis, rate, out, log)
    tuning = propose_and_write(read_axis(args.source), current, args, out, log)
    result = dict(proposal=tuning.prop, before=tuning.before, tuning=tuning)
    if not args.apply:
        return result
    assert rec is not None
    return result | verify(rec, axis, tuning, current, args, out, log)


def measure_first(axis, name: str, rate: float, out: pathlib.Path, log=print) -> pathlib.Path:
    """Without --from: identify with its defaults on the axis, into OUT/identify (returned)."""
    settings = default_settings(name, rate)
    idir = out / 'identify'
    idir.mkdir(exist_ok=True)
    log(f'autotune: measuring the axis first (identify into {idir})')
    try:
        identify(axis, settings, idir, log=log)
    except IdentifyError as e:
        raise AutotuneError(f'identify: {e}') from None
    return idir


def verify(rec: MoveRecorder, axis, tuning: Tuning, current: dict, args, out: pathlib.Path,
           log=print) -> dict:
    """--apply: the moves before and after the proposal is loaded (verification_runs), the
    registers put back with --restore or where a move after did not come to rest, the
    before/after table printed and written (write_verification); {runs, at_rest}."""
    rec.coulomb = tuning.prop.registers['friction_ff']
    saved = {k: current[k] for k in at.GAIN_REGISTERS + rest.REST_REGISTERS}
    runs = verification_runs(rec, axis, tuning, saved, args, out, log)
    if args.restore:
        axis.set(saved)
        log('autotune: registers put back (--restore)')
    write_verification(out, runs, tuning, args, log)
    unsettled = [m.label for m in runs['after'] if not m.settled]
    if unsettled and not args.restore:
        axis.set(saved)
        log(f'autotune: the proposal did not bring every move to rest ({", ".join(unsettled)}):'
            ' registers put back')
    return dict(runs=runs, at_rest=not unsettled)


def verification_runs(rec: MoveRecorder, axis, tuning: Tuning, saved: dict, args,
                      out: pathlib.Path, log=print) -> dict:
    """The demo's moves with the current registers, the rest settings chosen (choose_rest),
    the proposal written again and loaded, the demo's moves with it: {'before', ['gains
    alone',] 'after': [MoveResult]}. On an error after the first moves the registers are put
    back (`saved`) before it is raised."""
    cpm = tuning.cpm
    changed = False
    try:
        log('autotune: verification, current registers')
        runs = {'before': run_moves(rec, axis, cpm, args.move_timeout, args.rest, log,
                                    tolerate=True)}
        changed = True
        if tuning.plan.test:
            choose_rest(rec, axis, tuning, log)
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
    return runs


def choose_rest(rec: MoveRecorder, axis, tuning: Tuning, log=print) -> None:
    """The rest settings tried with short test moves (rest.search over the plan's candidates),
    the shipped ones first for the record; the first that holds the slide at rest is the
    tuning's, else the widest."""
    log('autotune: the rest settings, tried with short test moves (rest.search)')
    trial = test_moves(rec, axis, tuning.registers, tuning.cpm)
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


def write_verification(out: pathlib.Path, runs: dict, tuning: Tuning, args, log=print) -> None:
    """The before/after table printed and added to report.md, steps.png (plotting.steps),
    verification.yaml."""
    evs = {'before': tuning.before, 'gains alone': tuning.prop.evaluation,
           'after': tuning.prop.evaluation}
    table = at.format_verification(runs, evs)
    log(table)
    png = out / 'steps.png'
    plot_steps(png, runs, title=f'axis {args.axis}: the demo\'s moves, before and after '
               f'autotune --preset {tuning.prop.preset.name} (controller joint_states)')
    with open(out / 'report.md', 'a') as f:
        f.write('\n' + table + '\n')
    summary = {name: dict(
        gain_margin_db=float(evs[name].gain_margin_db),
        phase_margin_deg=float(evs[name].phase_margin_deg),
        crossover_hz=float(evs[name].crossover_hz or 0.0),
        bandwidth_hz=float(evs[name].bandwidth_hz),
        moves=[move_summary(m) for m in moves])
        for name, moves in runs.items()}
    summary['rest'] = rest_summary(tuning)
    (out / 'verification.yaml').write_text(yaml.safe_dump(summary, sort_keys=False,
                                                          allow_unicode=True))
    log(f'autotune: wrote {png}')


def move_summary(m: at.MoveResult) -> dict:
    """verification.yaml's record of one move."""
    j = m.rest
    return dict(move=m.label, target=m.target, settle_ms=float(m.settle_ms),
                overshoot_counts=float(m.overshoot), final_error_counts=float(m.final_error),
                output_pp_v=float(m.output_pp), at_rest=bool(j.settled),
                rest=j.describe(), moved_counts=float(j.moved), output_turns=int(j.output_turns),
                limit_cycle_period_s=None if j.done or not math.isfinite(j.period)
                else float(j.period),
                limit_cycle_amplitude_counts=None if j.done else float(j.amplitude),
                true_final_error_counts=None if m.true_error is None else float(m.true_error))


def rest_summary(tuning: Tuning) -> dict:
    """verification.yaml's record of the rest settings: the slip, the proposal and the
    accuracy it promises, the shipped settings tried, every candidate tried."""
    control = tuning.control
    return dict(
        slip_counts=tuning.plan.slip_counts, proposed=str(tuning.rest),
        window_counts=tuning.rest.window, aid_share=tuning.rest.aid_share,
        promise=rest.describe_promise(tuning.registers()['window_centre'],
                                      tuning.registers()['fine_position_tolerance']
                                      * tuning.cpm),
        control=None if control is None else dict(
            tried=str(control.candidate), at_rest=control.ok,
            reason=control.reason, moves=control.moves,
            hunted=control.hunted),
        trials=[dict(tried=str(t.candidate), at_rest=t.ok, reason=t.reason,
                     settle_ms=[float(x) for x in t.settle_ms]) for t in tuning.trials])
