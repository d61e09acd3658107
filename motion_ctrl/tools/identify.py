"""`identify`: measure an axis over ROS, fit the two-mass model, write a Bode plot (the ROS shell
of motion_ctrl/analysis/identify.py; Kollmorgen WorkBench's Bode measurement, Beckhoff TwinCAT's
base motion, PMAC's gather).

It talks to the controller like any ROS user, so it works against any plant on the `command` /
`encoders` topics: registers through the parameter services, runs started with `<axis>/excite`,
each run's every servo tick read back from the latched `<axis>/gather` (no sample lost to DDS),
friction from `target_velocity` jogs and the output [V] in `joint_states`. It never reads
`plant_states`.

The measurement, with the loop closed as the axis is tuned (the excitation is the instrument,
G = S_ry / S_ru, so the feedback does not bias it):

1. friction: jogs at ±v and ±2v; the mean output at constant velocity is
   coulomb·sign(v) + viscous·v + offset (analysis.identify.friction); then a creep each way
   (--creep, 0.2 mm/s), slow enough that a sticky slide sticks and slips: its breakaway
   friction, the output's peak before each slip (analysis.identify.breakaway);
2. a stepped sine over the band on a slow base motion (the nut stays on one flank of the
   backlash, the friction keeps its sign), volts -> motor and -> load position;
3. a second stepped sine, denser and smaller, around the resonance the first one found (a
   slide held against its nut by friction alone lifts off it when it vibrates harder than
   friction / mass: the amplitude there is kept low, the dwell long);
4. six stepped sines below the anti-resonance the first two located, on base motions of six
   speeds, for the load/motor position ratio that locates the anti-resonance (the split of the
   inertia rests on it);
5. the two-mass fit over the points of runs 1-2 whose coherence reaches 0.9, with 0, 1 or 2
   ticks of delay (the best), its anti-resonance held at the one the ratio gives, and, from one
   absolute reference (--slide-mass or --force-per-volt: the response alone fixes only ratios),
   the masses in kg and the amplifier's force per volt.

During the runs kp and kd are lowered (--soft-loop), ki is 0 and the friction feedforward off
(friction must hold the nut on one flank of the backlash): the motion near the
anti-resonance is a fraction of a count on both encoders, and a stiff loop answering each count
moves the slide in step with the encoders' own quantisation, which biases what they report of
such a sine by up to ±15 % (consistently for a given base speed). The registers are put back
after.

`--spawn` starts the simulated slide itself (as `calibrate`), `--lockstep` as the lockstep
simulation, `--plant NAME:=VALUE` changes it.
"""
from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time

import numpy as np

from motion_ctrl.analysis import identify as idf
from motion_ctrl.core import excitation as ex
from motion_ctrl.procedures.session import pair, session_arguments

EXCITATION_REGISTERS = ('excitation_signal', 'excitation_amplitude', 'excitation_band_low',
                        'excitation_band_high', 'excitation_duration', 'excitation_points',
                        'excitation_budget', 'excitation_velocity')
MIN_COHERENCE = 0.9
FINE_BAND = (0.8, 1.1)        # the second run, around the first run's resonance
#: the ratio runs: a band below the anti-resonance run 1 found, where X_load / X_motor is 2-7
RATIO_BAND = (0.75, 0.93)
#: ... at these multiples of --velocity, one run each (the count-rate aliases of the encoders
#: differ from run to run, and so does the bias their quantisation leaves: averaged)
RATIO_VELOCITIES = (1.05, -1.5, 1.2, -0.8, 1.35, -1.15)
#: ... with an amplitude that keeps the slide's vibration to this share of friction / mass
#: (taken as the axis' Coulomb friction over the slide's inertia: an upper bound of the slide's
#: own), so that it stays on its nut flank
RATIO_ACCELERATION_SHARE = 0.3
RATIO_MAX_AMPLITUDE = 0.15    # V
#: the loop registers lowered for the runs (the rest of the axis' registers unchanged)
LOOP_REGISTERS = ('kp', 'ki', 'kd', 'kvff', 'friction_ff', 'friction_ff_at_rest')


class IdentifyError(RuntimeError):
    pass


class Excitation:
    """Runs on one axis of a running controller: registers set, <axis>/excite, the record
    from <axis>/gather."""

    def __init__(self, axis_under_test):
        from std_msgs.msg import Float64MultiArray
        import msg_defs as md
        self.axis = axis_under_test
        self.client = axis_under_test.client
        self.records: dict[int, tuple] = {}          # run -> (columns, meta)
        # Subscribed once, now (a reader joining later holds the controller up: design notes);
        # latched: a record that is late or resent still arrives whole.
        self.client.create_subscription(Float64MultiArray, md.gather_topic(self.axis.axis),
                                        self._on_gather, md.GATHER_QOS)

    def _on_gather(self, msg) -> None:
        import msg_defs as md
        try:
            columns, meta = md.read_gather(msg)
        except ValueError:
            return
        self.records[int(meta.get('run', -1))] = (columns, meta)

    def run(self, settings: dict, timeout: float) -> tuple[dict, dict]:
        """Set the excitation_* registers, start the run, return its record ({column: array},
        meta) once it has ended."""
        from std_srvs.srv import Trigger
        import re
        self.axis.set(settings)
        from msg_defs.status import Status
        name = self.axis.axis
        cli = self.client.axis_services[(name, 'excite')]
        # The base motion of the run before decelerates after its record came: at rest first.
        if not self.client.spin_until(
                lambda: (self.client.status[name] or 0) & Status.MOTION_DONE, 10.0):
            raise IdentifyError(f'{name}: not at rest (MOTION_DONE) within 10 s after the run '
                                'before')
        if not self.client.spin_until(cli.service_is_ready, 10.0):
            raise IdentifyError(f'{name}/excite is not there')
        # Not resent: a second request while the run goes would only be refused.
        reply = self.client.answer(lambda: cli.call_async(Trigger.Request()), 10.0,
                                   resend_after=10.0)
        if not reply.success:
            raise IdentifyError(f'{name}/excite refused: {reply.message}')
        found = re.search(r'run (\d+)', reply.message)
        if found is None:
            raise IdentifyError(f'{name}/excite answered without a run number: {reply.message}')
        run = int(found.group(1))
        if not self.client.spin_until(lambda: run in self.records, timeout):
            raise IdentifyError(f'run {run}: no record on {name}/gather within {timeout:g} s')
        columns, meta = self.records.pop(run)
        if meta.get('ended') != 'done':
            raise IdentifyError(f'run {run} ended early: {meta.get("ended")}')
        return columns, meta


def stepped(amplitude, band, points, dwell, velocity, rate) -> tuple[dict, ex.Excitation]:
    """The registers of a stepped-sine run on a base motion, and the signal they give (the
    controller builds the same from them: excitation.from_registers)."""
    duration = points * dwell
    settings = dict(excitation_signal='stepped_sine', excitation_amplitude=float(amplitude),
                    excitation_band_low=float(band[0]), excitation_band_high=float(band[1]),
                    excitation_duration=float(duration), excitation_points=int(points),
                    excitation_velocity=float(velocity),
                    # the base motion, its ramps and a margin for the vibration
                    excitation_budget=float(abs(velocity) * (duration + 1.0) + 0.005))
    return settings, ex.from_registers(settings, rate)


def measure(run, settings, signal, timeout):
    """(motor, load) responses of one stepped-sine run."""
    columns, meta = run(settings, timeout)
    n = signal.ticks
    if columns['excitation'].size != n or not np.allclose(columns['excitation'], signal.signal):
        raise IdentifyError(f'run {meta.get("run")}: the recorded excitation is not the signal '
                            'its registers describe')
    u = columns['output']
    return (idf.stepped_sine_response(signal, u, columns['motor']),
            idf.stepped_sine_response(signal, u, columns['load']))


def best_fit(motor, load, band):
    """The two-mass fit with the whole ticks of delay (0-2) that fit best."""
    fits = []
    for delay in (0, 1, 2):
        try:
            f = idf.fit_two_mass(motor, load, band=band, min_coherence=MIN_COHERENCE,
                                 delay_ticks=delay)
        except ValueError as e:
            last = e
            continue
        fits.append((f.rms_error_db + f.rms_error_deg / 10.0, delay, f))
    if not fits:
        raise IdentifyError(f'no fit: {last}')
    return min(fits, key=lambda x: x[:2])[2]


def first_fit(motor, load, band):
    """Run 1's fit, which places the later runs. A resonance outside the band, or no
    anti-resonance below it, is no place to measure around (once, in CI, a first run "found"
    474 Hz on a 243 Hz slide and the fine run searched there): fitted again on the lower three
    quarters of the band, where the encoders see most, and refused if that does not hold
    either."""
    lo, hi = band
    for upper in (hi, 0.75 * hi):
        fit = best_fit(motor, load, (lo, upper))
        if lo < fit.resonance_hz < upper and fit.inertia_ratio >= idf.MIN_INERTIA_RATIO:
            return fit
    raise IdentifyError(f'run 1 gives no resonance with an anti-resonance below it inside '
                        f'{lo:g}-{hi:g} Hz (fit: {fit.resonance_hz:.1f} Hz, slide/motor '
                        f'{fit.inertia_ratio:.3g}); a wider --band or a larger --amplitude')


def soft_loop(regs: dict, divisor: float) -> dict:
    """The loop registers for the runs: kp and kd divided by `divisor`, no integrator, kvff
    keeping its viscous share (PMAC form: kvff = kd + viscous)."""
    kd = regs['kd'] / divisor
    return dict(kp=regs['kp'] / divisor, ki=0.0, kd=kd, kvff=regs['kvff'] - regs['kd'] + kd)


def run_loop(regs: dict, divisor: float) -> dict:
    """The registers the runs change: the soft loop (`divisor` 1: the gains as they are), and
    no friction feedforward. The runs rely on friction to hold the nut on one flank of the
    backlash; a feedforward that cancels it lets the nut lift off under the sine (on the
    default slide with friction_ff 0.242 V, the split came out at a slide/motor inertia ratio
    of 0.37-0.84 against the true 0.16)."""
    loop = soft_loop(regs, divisor) if divisor != 1.0 else {}
    return loop | {'friction_ff': 0.0, 'friction_ff_at_rest': 0.0}


def ratio_amplitude(fit, coulomb, band, cap=RATIO_MAX_AMPLITUDE):
    """The ratio runs' amplitude [V]: the slide's acceleration the fitted model predicts over
    `band` kept to RATIO_ACCELERATION_SHARE of Coulomb friction / slide inertia (the slide
    lifts off its nut flank above friction / mass), at most `cap`."""
    f = np.linspace(band[0], band[1], 32)
    accel = float(np.max(np.abs(fit.response(f, output='load')) * (2 * math.pi * f) ** 2))
    limit = RATIO_ACCELERATION_SHARE * abs(coulomb) / fit.load_inertia
    return float(min(cap, limit / accel)) if accel > 0 and limit > 0 else cap


def friction_runs(axis, client, speeds, samples, timeout=10.0, log=print):
    """Jog at each speed both ways (+v, -v: back where it started), mean output and velocity at
    constant velocity (MOTION_AT_VELOCITY) over `samples` joint_states."""
    import msg_defs as md
    from msg_defs.status import Status
    name = axis.axis
    velocities, volts = [], []
    for speed in speeds:
        for v in (speed, -speed):
            client.pub_velocity.publish(md.joint_state(client.get_clock().now().to_msg(),
                                                       [name], velocity=[v]))
            mark = len(client.status_log[name])
            at = client.spin_until(lambda: any(w & Status.MOTION_AT_VELOCITY for _, w in
                                               client.status_log[name][mark:]), timeout)
            if not at:
                raise IdentifyError(f'jog at {v:g} m/s: not MOTION_AT_VELOCITY within '
                                    f'{timeout:g} s (status {Status(client.status[name] or 0)!r})')
            msgs = axis.samples(samples, timeout)
            i = list(msgs[0].name).index(name)
            velocities.append(float(np.mean([m.velocity[i] for m in msgs])))
            volts.append(float(np.mean([m.effort[i] for m in msgs])))
            if client.stop_jogs([name], timeout) is None:
                raise IdentifyError(f'jog at {v:g} m/s: no MOTION_DONE after the stop')
            log(f'identify: jog {v * 1e3:+.1f} mm/s: mean output {volts[-1]:+.4f} V')
    return idf.friction(velocities, volts), velocities, volts


def creep_runs(axis, client, speed: float, seconds: float, rate: float, counts_per_m: float,
               timeout: float = 10.0, log=print) -> list:
    """A creep at +speed, then -speed, `seconds` each: the breakaway friction each way
    (analysis.identify.breakaway) from every joint_states sample of it."""
    import msg_defs as md
    name = axis.axis
    found = []
    for v in (speed, -speed):
        client.pub_velocity.publish(md.joint_state(client.get_clock().now().to_msg(),
                                                   [name], velocity=[v]))
        msgs = axis.samples(max(10, int(round(seconds * rate))), timeout + seconds)
        if client.stop_jogs([name], timeout) is None:
            raise IdentifyError(f'creep at {v:g} m/s: no MOTION_DONE after the stop')
        i = list(msgs[0].name).index(name)
        t = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in msgs]
        b = idf.breakaway(t, [m.position[i] for m in msgs], [m.effort[i] for m in msgs],
                          counts_per_m)
        found.append(b)
        log(f'identify: creep {v * 1e3:+.2f} mm/s: ' + (
            f'{b.slips} slips, breakaway {b.breakaway:+.4f} V (the output before each)'
            if b.breakaway is not None else
            'the slide crept without sticking (breakaway = sliding friction)')
            + f', mean output {b.creep:+.4f} V')
    return found


def identify(axis, args, out: pathlib.Path, log=print) -> dict:
    """The whole measurement on an axis of a ready controller; returns what it found and wrote."""
    from motion_ctrl.ros.client import FAULTS
    from msg_defs.status import Status
    client = axis.client
    word = client.status[args.axis] or 0
    if word & FAULTS or not word & Status.ENABLED:
        raise IdentifyError(f'axis {args.axis} is not ready ({Status(word)!r}): reset and '
                            f'enable it first ({args.axis}/reset, {args.axis}/enable)')
    regs = axis.get(*EXCITATION_REGISTERS)
    rate = args.servo_rate
    lo, hi = args.band
    if not 0 < lo < hi < rate / 2:
        raise IdentifyError(f'--band {lo:g},{hi:g}: must be 0 < low < high < {rate / 2:g} Hz '
                            '(half the servo rate)')
    runner = Excitation(axis)
    t0 = time.monotonic()
    loop = axis.get(*LOOP_REGISTERS)
    try:
        fr, vels, volts = friction_runs(axis, client, (args.velocity, 2 * args.velocity),
                                        args.friction_samples, log=log)
        creeps = creep_runs(axis, client, args.creep, args.creep_time, rate,
                            float(axis.get('load_counts_per_m')['load_counts_per_m']),
                            log=log) if args.creep > 0 else []
        soft = run_loop(loop, args.soft_loop)
        if args.soft_loop != 1.0:
            log(f'identify: loop registers for the runs: kp {soft["kp"]:.4g}, ki 0, kd '
                f'{soft["kd"]:.4g}, kvff {soft["kvff"]:.4g}, no friction feedforward '
                f'(--soft-loop {args.soft_loop:g}; put back after)')
        else:
            log('identify: no friction feedforward during the runs (put back after)')
        axis.set(soft)
        settings, coarse = stepped(args.amplitude, (lo, hi), args.points, args.dwell,
                                   args.velocity, rate)
        log(f'identify: run 1: stepped sine {args.amplitude:g} V, {lo:g}-{hi:g} Hz, '
            f'{args.points} points x {args.dwell:g} s on {args.velocity * 1e3:g} mm/s')
        m1, l1 = measure(runner.run, settings, coarse, coarse.duration + 30.0)
        first = first_fit(m1, l1, (lo, hi))
        f_lo = max(lo, FINE_BAND[0] * first.resonance_hz)
        f_hi = min(0.95 * rate / 2, FINE_BAND[1] * first.resonance_hz)
        settings, fine = stepped(args.fine_amplitude, (f_lo, f_hi), args.fine_points,
                                 args.fine_dwell, -args.velocity, rate)
        log(f'identify: run 2: stepped sine {args.fine_amplitude:g} V, {f_lo:.1f}-{f_hi:.1f} Hz '
            f'(around {first.resonance_hz:.1f} Hz), {args.fine_points} points x '
            f'{args.fine_dwell:g} s on {-args.velocity * 1e3:g} mm/s')
        m2, l2 = measure(runner.run, settings, fine, fine.duration + 30.0)
        ratio_runs: list[tuple[idf.FrequencyResponse, idf.FrequencyResponse]] = []
        if args.ratio_points:
            fa = first.antiresonance_hz
            try:        # runs 1 and 2 have a few points of the ratio already: a closer start
                fa = idf.fit_two_mass_on_ratio(idf.merge([m1, m2]), idf.merge([l1, l2]),
                                               band=(lo, hi), min_coherence=MIN_COHERENCE,
                                               delay_ticks=first.delay_ticks)[1].frequency_hz
            except ValueError:
                pass
            r_band = (max(lo, RATIO_BAND[0] * fa), RATIO_BAND[1] * fa)
            amp = args.ratio_amplitude or ratio_amplitude(first, fr.coulomb, r_band)
            for k in RATIO_VELOCITIES:
                v = k * args.velocity
                settings, sig = stepped(amp, r_band, args.ratio_points, args.ratio_dwell, v,
                                        rate)
                log(f'identify: run {3 + len(ratio_runs)}: stepped sine {amp:.3g} V, '
                    f'{r_band[0]:.1f}-{r_band[1]:.1f} Hz (below the anti-resonance, '
                    f'{fa:.1f} Hz from runs 1-2), {args.ratio_points} points x '
                    f'{args.ratio_dwell:g} s on {v * 1e3:g} mm/s')
                ratio_runs.append(measure(runner.run, settings, sig, sig.duration + 30.0))
    finally:
        axis.set({k: regs[k] for k in EXCITATION_REGISTERS} | loop)
    motor, load = idf.merge([m1, m2]), idf.merge([l1, l2])
    fit = best_fit(motor, load, (lo, hi))
    ar = None
    if ratio_runs:
        ratio = (idf.merge([m for m, _ in ratio_runs]), idf.merge([r for _, r in ratio_runs]))
        try:
            fit, ar = idf.fit_two_mass_on_ratio(motor, load, ratio=ratio, band=(lo, hi),
                                                min_coherence=MIN_COHERENCE,
                                                delay_ticks=fit.delay_ticks)
        except ValueError as e:
            raise IdentifyError(f'the load/motor ratio gives no anti-resonance: {e}') from None
    seconds = time.monotonic() - t0
    ref = {}
    if args.slide_mass is not None:
        ref = dict(slide_mass=args.slide_mass)
    elif args.force_per_volt is not None:
        ref = dict(force_per_volt=args.force_per_volt)
    si = idf.physical_units(fit, **ref) if ref else {}
    used = motor.select((lo, hi), MIN_COHERENCE) | load.select((lo, hi), MIN_COHERENCE)
    inband = motor.select((lo, hi))
    both = np.maximum(motor.coherence, load.coherence)
    result = dict(
        resonance_hz=fit.resonance_hz, resonance_damping=fit.resonance_damping,
        antiresonance_hz=fit.antiresonance_hz,
        antiresonance_damping=fit.antiresonance_damping,
        accel_per_volt=fit.accel_per_volt, viscous_pole=fit.model.viscous_pole,
        load_zero=fit.model.load_zero, sample_period=1.0 / rate,
        inertia=fit.inertia, motor_inertia=fit.motor_inertia,
        load_inertia=fit.load_inertia, inertia_ratio=fit.inertia_ratio,
        stiffness=fit.stiffness, delay_ticks=fit.delay_ticks, points=fit.points,
        frequencies=int(np.count_nonzero(inband)), band=[float(lo), float(hi)],
        coherence_min=float(both[inband].min()),
        coherent_fraction=float(np.count_nonzero(used & inband) / np.count_nonzero(inband)),
        rms_error_db=fit.rms_error_db, rms_error_deg=fit.rms_error_deg,
        antiresonance_from='load/motor ratio' if ar else 'two-mass fit',
        ratio_points=ar.points if ar else 0,
        ratio_rms_error_db=ar.rms_error_db if ar else None,
        ratio_rms_error_deg=ar.rms_error_deg if ar else None,
        coulomb=fr.coulomb, viscous=fr.viscous, friction_offset=fr.offset,
        coulomb_pos=fr.coulomb + fr.offset, coulomb_neg=fr.coulomb - fr.offset,
        seconds=seconds)
    for side, b, coulomb in zip(('pos', 'neg'), creeps, (fr.coulomb + fr.offset,
                                                        fr.coulomb - fr.offset)):
        # a slide that crept without sticking breaks away at its sliding friction
        result[f'breakaway_{side}'] = abs(b.breakaway) if b.breakaway is not None else coulomb
        result[f'stick_slips_{side}'] = b.slips
    if creeps:
        result['creep_velocity'] = args.creep
    if si:
        fpv = si['force_per_volt']
        result |= dict(force_per_volt=fpv, motor_mass=si['motor_mass'],
                       slide_mass=si['slide_mass'], stiffness_n_per_m=si['stiffness'],
                       coulomb_n=fr.coulomb * fpv, viscous_n_s_per_m=fr.viscous * fpv)
        if args.lead is not None:
            result['motor_inertia_kg_m2'] = si['motor_mass'] * (args.lead / (2 * math.pi)) ** 2
            if args.torque_constant is not None:
                result['amplifier_gain'] = fpv * args.lead / (2 * math.pi) / args.torque_constant
    result = {k: (float(v) if isinstance(v, (float, np.floating)) else v)
              for k, v in result.items()}
    report = format_report(result, ref)
    log(report)
    import yaml
    (out / 'identify.yaml').write_text(yaml.safe_dump(result, sort_keys=False))
    (out / 'report.md').write_text(report + '\n')
    from motion_ctrl.analysis.autotune import RESPONSE_FILE, write_response
    write_response(out / RESPONSE_FILE, motor, load)      # the measured points, for autotune
    png = out / 'bode.png'
    idf.plot_bode(png, motor, load, fit, min_coherence=MIN_COHERENCE,
                  ratio=idf.load_motor_ratio(*ratio) if ratio_runs else None,
                  title=f'axis {args.axis}: volts -> motor and load position, loop closed '
                        f'(stepped sine on a {args.velocity * 1e3:g} mm/s base motion)')
    log(f'identify: wrote {out / "identify.yaml"}, {out / RESPONSE_FILE}, {out / "report.md"} '
        f'and {png} '
        f'({seconds:.1f} s)')
    problems = idf.doubts(fit, result['coherent_fraction'])
    if problems:
        raise IdentifyError('the measurement does not give a model of the axis: '
                            + '; '.join(problems) + f' (look at {png}). A larger --amplitude '
                            'or a longer --dwell where the plot is scattered; on a machine '
                            'whose servo ticks jitter, the lockstep simulation (--spawn '
                            '--lockstep) or a quieter hour')
    return result


def format_report(r: dict, ref: dict) -> str:
    rows = [('resonance', f'{r["resonance_hz"]:.1f}', 'Hz',
             f'damping {r["resonance_damping"]:.3f}'),
            ('anti-resonance', f'{r["antiresonance_hz"]:.1f}', 'Hz',
             f'damping {r["antiresonance_damping"]:.3f}'
             + (f'; load/motor ratio, {r["ratio_points"]} points'
                if r.get('ratio_points') else '')),
            ('total inertia (kaff)', f'{r["inertia"]:.4f}', 'V·s²/m',
             f'{r["accel_per_volt"]:.3f} m/s² per V'),
            ('motor-side inertia', f'{r["motor_inertia"]:.4f}', 'V·s²/m', ''),
            ('slide inertia', f'{r["load_inertia"]:.4f}', 'V·s²/m',
             f'ratio slide/motor {r["inertia_ratio"]:.3f}'),
            ('stiffness', f'{r["stiffness"]:.4g}', 'V/m', ''),
            ('Coulomb friction', f'{r["coulomb"]:.4f}', 'V',
             f'jogs both ways: +{r["coulomb_pos"]:.4f} / -{r["coulomb_neg"]:.4f}'),
            ('viscous friction', f'{r["viscous"]:.4f}', 'V·s/m', 'jogs at two speeds')]
    if 'breakaway_pos' in r:
        creep = f'creep at ±{r["creep_velocity"] * 1e3:g} mm/s'
        rows.append(('breakaway friction', f'+{r["breakaway_pos"]:.4f} / '
                     f'-{r["breakaway_neg"]:.4f}', 'V', (
                         f'{creep}: the output before the slide broke away, '
                         f'{r["stick_slips_pos"]} / {r["stick_slips_neg"]} slips')
                     if r['stick_slips_pos'] or r['stick_slips_neg'] else
                     f'{creep}: the slide crept without sticking (= Coulomb)'))
    rows.append(('delay', f'{r["delay_ticks"]}', 'ticks', 'best fit'))
    if 'force_per_volt' in r:
        how = ('from --slide-mass' if 'slide_mass' in ref else 'given (--force-per-volt)')
        rows += [('amplifier force per volt', f'{r["force_per_volt"]:.3f}', 'N/V', how),
                 ('motor-side inertia', f'{r["motor_mass"]:.3f}', 'kg', 'as a mass at the slide'),
                 ('slide mass', f'{r["slide_mass"]:.3f}', 'kg', ''),
                 ('stiffness', f'{r["stiffness_n_per_m"]:.4g}', 'N/m', ''),
                 ('Coulomb friction', f'{r["coulomb_n"]:.3f}', 'N', ''),
                 ('viscous friction', f'{r["viscous_n_s_per_m"]:.2f}', 'N·s/m', '')]
        if 'motor_inertia_kg_m2' in r:
            rows.append(('motor inertia', f'{r["motor_inertia_kg_m2"]:.4g}', 'kg·m²',
                         'with --lead'))
        if 'amplifier_gain' in r:
            rows.append(('amplifier gain', f'{r["amplifier_gain"]:.4f}', 'A/V',
                         'with --torque-constant'))
    lines = ['| quantity | value | unit | note |', '|---|---:|---|---|']
    lines += [f'| {a} | {b} | {c} | {d} |' for a, b, c, d in rows]
    lines.append(f'\nfit over {r["points"]} points (motor and load) with coherence >= '
                 f'{MIN_COHERENCE:g} in {r["band"][0]:g}-{r["band"][1]:g} Hz; '
                 f'{r["coherent_fraction"] * 100:.0f} % of the {r["frequencies"]} frequencies '
                 f'measured coherently on motor or load (lowest of the better one '
                 f'{r["coherence_min"]:.3f}); residual {r["rms_error_db"]:.2f} dB, '
                 f'{r["rms_error_deg"]:.1f}° rms')
    return '\n'.join(lines)


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog='identify', description='Measure an axis through the running controller (loop '
        'closed, stepped sine on a slow base motion, every servo tick gathered), fit the '
        'two-mass model, print it and write a Bode plot.')
    ap.add_argument('--axis', default='x')
    ap.add_argument('--band', type=pair, default=(20.0, 400.0), metavar='LO,HI',
                    help='frequency band [Hz] (default 20,400)')
    ap.add_argument('--amplitude', type=float, default=0.05,
                    help='run 1 amplitude [V] (default 0.05)')
    ap.add_argument('--points', type=int, default=48, help='run 1 frequencies (default 48)')
    ap.add_argument('--dwell', type=float, default=0.5,
                    help='run 1 time per frequency [s] (default 0.5)')
    ap.add_argument('--fine-amplitude', type=float, default=0.03,
                    help='run 2 (around the resonance) amplitude [V] (default 0.03)')
    ap.add_argument('--fine-points', type=int, default=16, help='run 2 frequencies (16)')
    ap.add_argument('--fine-dwell', type=float, default=1.0,
                    help='run 2 time per frequency [s] (default 1.0)')
    ap.add_argument('--ratio-points', type=int, default=12,
                    help='runs 3-8 (below the anti-resonance, for the load/motor ratio that '
                    'locates it): frequencies per run (12; 0: no such runs, the anti-resonance '
                    'from the two-mass fit alone)')
    ap.add_argument('--ratio-dwell', type=float, default=1.0,
                    help='runs 3-8: time per frequency [s] (default 1.0)')
    ap.add_argument('--ratio-amplitude', type=float, default=None,
                    help='runs 3-8: amplitude [V] (default: from run 1, the slide kept on its '
                    'nut flank)')
    ap.add_argument('--soft-loop', type=float, default=16.0,
                    help='kp and kd divided by this, ki 0, during the runs (default 16; 1: the '
                    'registers as they are). The loop then barely answers the encoders\' '
                    'single counts, which otherwise move the slide in step with their own '
                    'quantisation and bias what the encoders report of a sub-count sine')
    ap.add_argument('--velocity', type=float, default=0.01,
                    help='base motion [m/s] (run 1 forward, run 2 back; friction jogs at it '
                    'and twice it; default 0.01)')
    ap.add_argument('--friction-samples', type=int, default=300,
                    help='joint_states samples averaged per friction jog (default 300)')
    ap.add_argument('--creep', type=float, default=0.0002,
                    help='creep velocity [m/s] for the breakaway friction, each way (default '
                    '0.0002: a sticky slide sticks and slips; 0: no creep)')
    ap.add_argument('--creep-time', type=float, default=1.5,
                    help='time of each creep [s] (default 1.5)')
    ref = ap.add_mutually_exclusive_group()
    ref.add_argument('--slide-mass', type=float, default=None,
                     help='the slide\'s mass [kg], the one absolute reference: masses in kg, '
                     'the amplifier\'s force per volt')
    ref.add_argument('--force-per-volt', type=float, default=None,
                     help='or the amplifier\'s force per volt [N/V] as the reference')
    ap.add_argument('--lead', type=float, default=None,
                    help='screw lead [m/rev]: the motor inertia in kg·m² too')
    ap.add_argument('--torque-constant', type=float, default=None,
                    help='motor Kt [N·m/A] (with --lead): the amplifier gain in A/V too')
    ap.add_argument('--servo-rate', type=float, default=None,
                    help=argparse.SUPPRESS)     # read from the controller
    session_arguments(ap, 'identify', 'x.slide_mass:=10.0')
    return ap


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if args.lockstep and not args.spawn:
        print('identify: --lockstep needs --spawn', file=sys.stderr)
        return 2
    bad = [n for n in ('amplitude', 'fine_amplitude', 'dwell', 'fine_dwell', 'velocity',
                       'ratio_dwell', 'soft_loop', 'creep_time') if not getattr(args, n) > 0]
    if not args.creep >= 0:
        bad.append('creep')
    if args.ratio_amplitude is not None and not args.ratio_amplitude > 0:
        bad.append('ratio_amplitude')
    bad += [n for n in ('points', 'fine_points', 'friction_samples') if getattr(args, n) < 2]
    if args.ratio_points and args.ratio_points < 3:
        bad.append('ratio_points')
    if bad:
        print(f'identify: --{bad[0].replace("_", "-")} must be > 0 (points, samples: >= 2)',
              file=sys.stderr)
        return 2
    from rclpy.parameter import parameter_value_to_python
    from motion_ctrl.procedures.session import SessionError, axis_session
    try:
        with axis_session(args, 'identify', services=True) as (client, axis, out):
            rate = client.answer(lambda: axis.params.get_parameters(['servo_rate'])).values[0]
            args.servo_rate = float(parameter_value_to_python(rate))  # type: ignore[arg-type]
            identify(axis, args, out)
    except (IdentifyError, SessionError) as e:
        print(f'identify: {e}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
