"""identify's measurement on a live axis (Kollmorgen WorkBench's Bode measurement, Beckhoff
TwinCAT's base motion, PMAC's gather), run by the `identify` command and by `autotune` before it
proposes: the runs, the fit of their records (motion_ctrl.analysis.identify) and the files.

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

rclpy, the message packages and motion_ctrl.ros are imported inside the functions that use
them: a tool's `--help` and autotune's offline mode start without them (0.14-0.41 s of imports,
measured 2026-11-27) and run where ROS is blocked (the core tests import these modules:
`scripts/test -m core`).
"""
from __future__ import annotations

import argparse
import math
import pathlib
import re
import time
from dataclasses import dataclass

import numpy as np
import yaml

import msg_defs as md
from motion_ctrl.analysis import identify as idf
from motion_ctrl.analysis.autotune import RESPONSE_FILE, write_response
from motion_ctrl.core import excitation as ex
from motion_ctrl.plotting.bode import plot_bode
from motion_ctrl.procedures.session import pair
from msg_defs.status import Status

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
    """What stops the measurement: the axis not ready, a run refused or ended early, no fit;
    the tools print it and exit 1."""


def identify_arguments(ap: argparse.ArgumentParser) -> None:
    """The measurement's options (identify's, but for the session's: session_arguments)."""
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


def default_settings(axis: str, rate: float) -> argparse.Namespace:
    """The measurement's options at their defaults on `axis` at servo `rate` [Hz] (autotune's
    run of identify)."""
    ap = argparse.ArgumentParser()
    identify_arguments(ap)
    args = ap.parse_args(['--axis', axis])
    args.servo_rate = rate
    return args


# ================================================================================================
# the axis

def servo_rate(axis) -> float:
    """The controller's servo_rate register [Hz]."""
    from rclpy.parameter import parameter_value_to_python
    rate = axis.client.answer(lambda: axis.params.get_parameters(['servo_rate'])).values[0]
    return float(parameter_value_to_python(rate))  # type: ignore[arg-type]


class Excitation:
    """Runs on one axis of a running controller: registers set, <axis>/excite, the record
    from <axis>/gather."""

    def __init__(self, axis_under_test):
        from std_msgs.msg import Float64MultiArray
        self.axis = axis_under_test
        self.client = axis_under_test.client
        self.records: dict[int, tuple] = {}          # run -> (columns, meta)
        # Subscribed once, now (a reader joining later holds the controller up: design notes);
        # latched: a record that is late or resent still arrives whole.
        self.client.create_subscription(Float64MultiArray, md.gather_topic(self.axis.axis),
                                        self._on_gather, md.GATHER_QOS)

    def _on_gather(self, msg) -> None:
        try:
            columns, meta = md.read_gather(msg)
        except ValueError:
            return
        self.records[int(meta.get('run', -1))] = (columns, meta)

    def run(self, settings: dict, timeout: float) -> tuple[dict, dict]:
        """Set the excitation_* registers, start the run, return its record ({column: array},
        meta) once it has ended."""
        from std_srvs.srv import Trigger
        self.axis.set(settings)
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


# ================================================================================================
# the runs

def friction_runs(axis, client, speeds, samples, timeout=10.0, log=print):
    """Jog at each speed both ways (+v, -v: back where it started), mean output and velocity at
    constant velocity (MOTION_AT_VELOCITY) over `samples` joint_states."""
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


@dataclass
class Runs:
    """What the runs gave: the friction of the jogs (analysis.identify.Friction) and the
    breakaway of the creeps (one each way, or none), the responses of runs 1 and 2 merged
    (volts -> motor, -> load) and the (motor, load) responses of the ratio runs."""
    friction: idf.Friction
    creeps: list
    motor: idf.FrequencyResponse
    load: idf.FrequencyResponse
    ratio_runs: list


def run_all(axis, runner: Excitation, args, loop: dict, log=print) -> Runs:
    """Steps 1-4 of the measurement: the friction jogs and creeps, the run loop set (the
    caller puts the registers back), run 1 over the band, run 2 around its resonance, the
    ratio runs."""
    client, rate = axis.client, args.servo_rate
    fr, _, _ = friction_runs(axis, client, (args.velocity, 2 * args.velocity),
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
    m1, l1, first = coarse_run(runner, args, log)
    m2, l2 = fine_run(runner, args, first, log)
    motor, load = idf.merge([m1, m2]), idf.merge([l1, l2])
    ratio_runs = ratio_run_series(runner, args, first, motor, load, fr, log) \
        if args.ratio_points else []
    return Runs(fr, creeps, motor, load, ratio_runs)


def coarse_run(runner: Excitation, args, log=print) -> tuple:
    """Run 1: the stepped sine over the band on the base motion forward; (motor, load, its
    fit)."""
    lo, hi = args.band
    settings, coarse = stepped(args.amplitude, (lo, hi), args.points, args.dwell,
                               args.velocity, args.servo_rate)
    log(f'identify: run 1: stepped sine {args.amplitude:g} V, {lo:g}-{hi:g} Hz, '
        f'{args.points} points x {args.dwell:g} s on {args.velocity * 1e3:g} mm/s')
    m1, l1 = measure(runner.run, settings, coarse, coarse.duration + 30.0)
    return m1, l1, first_fit(m1, l1, (lo, hi))


def fine_run(runner: Excitation, args, first: idf.TwoMassFit, log=print) -> tuple:
    """Run 2: denser and smaller, FINE_BAND around run 1's resonance, on the base motion
    back; (motor, load)."""
    rate = args.servo_rate
    f_lo = max(args.band[0], FINE_BAND[0] * first.resonance_hz)
    f_hi = min(0.95 * rate / 2, FINE_BAND[1] * first.resonance_hz)
    settings, fine = stepped(args.fine_amplitude, (f_lo, f_hi), args.fine_points,
                             args.fine_dwell, -args.velocity, rate)
    log(f'identify: run 2: stepped sine {args.fine_amplitude:g} V, {f_lo:.1f}-{f_hi:.1f} Hz '
        f'(around {first.resonance_hz:.1f} Hz), {args.fine_points} points x '
        f'{args.fine_dwell:g} s on {-args.velocity * 1e3:g} mm/s')
    return measure(runner.run, settings, fine, fine.duration + 30.0)


def ratio_run_series(runner: Excitation, args, first: idf.TwoMassFit,
                     motor: idf.FrequencyResponse, load: idf.FrequencyResponse,
                     fr: idf.Friction, log=print) -> list:
    """Runs 3-8: RATIO_BAND below the anti-resonance (as the ratio points of runs 1-2, `motor`
    and `load`, place it; else run 1's fit), one run at each of RATIO_VELOCITIES × --velocity,
    the amplitude kept to the slide's friction (ratio_amplitude); [(motor, load)]."""
    lo, hi = args.band
    fa = first.antiresonance_hz
    try:        # runs 1 and 2 have a few points of the ratio already: a closer start
        fa = idf.fit_two_mass_on_ratio(motor, load, band=(lo, hi), min_coherence=MIN_COHERENCE,
                                       delay_ticks=first.delay_ticks)[1].frequency_hz
    except ValueError:
        pass
    r_band = (max(lo, RATIO_BAND[0] * fa), RATIO_BAND[1] * fa)
    amp = args.ratio_amplitude or ratio_amplitude(first, fr.coulomb, r_band)
    out: list[tuple[idf.FrequencyResponse, idf.FrequencyResponse]] = []
    for k in RATIO_VELOCITIES:
        v = k * args.velocity
        settings, sig = stepped(amp, r_band, args.ratio_points, args.ratio_dwell, v,
                                args.servo_rate)
        log(f'identify: run {3 + len(out)}: stepped sine {amp:.3g} V, '
            f'{r_band[0]:.1f}-{r_band[1]:.1f} Hz (below the anti-resonance, '
            f'{fa:.1f} Hz from runs 1-2), {args.ratio_points} points x '
            f'{args.ratio_dwell:g} s on {v * 1e3:g} mm/s')
        out.append(measure(runner.run, settings, sig, sig.duration + 30.0))
    return out


# ================================================================================================
# the model and what is written

def fit_model(runs: Runs, band) -> tuple:
    """Step 5: the two-mass fit of runs 1-2 with its best delay, then with the anti-resonance
    the ratio runs locate held (analysis.identify.fit_two_mass_on_ratio); (fit, AntiResonance
    or None, the ratio runs' (motor, load) merged or None)."""
    fit = best_fit(runs.motor, runs.load, band)
    if not runs.ratio_runs:
        return fit, None, None
    ratio = (idf.merge([m for m, _ in runs.ratio_runs]),
             idf.merge([r for _, r in runs.ratio_runs]))
    try:
        fit, ar = idf.fit_two_mass_on_ratio(runs.motor, runs.load, ratio=ratio, band=band,
                                            min_coherence=MIN_COHERENCE,
                                            delay_ticks=fit.delay_ticks)
    except ValueError as e:
        raise IdentifyError(f'the load/motor ratio gives no anti-resonance: {e}') from None
    return fit, ar, ratio


def reference(args) -> dict:
    """The one absolute reference given: {'slide_mass': kg}, {'force_per_volt': N/V} or {}."""
    if args.slide_mass is not None:
        return dict(slide_mass=args.slide_mass)
    if args.force_per_volt is not None:
        return dict(force_per_volt=args.force_per_volt)
    return {}


def model_summary(fit: idf.TwoMassFit, ar, runs: Runs, band, rate: float) -> dict:
    """identify.yaml's model part: the fit, how much of the band it rests on, the ratio's."""
    lo, hi = band
    motor, load = runs.motor, runs.load
    used = motor.select((lo, hi), MIN_COHERENCE) | load.select((lo, hi), MIN_COHERENCE)
    inband = motor.select((lo, hi))
    both = np.maximum(motor.coherence, load.coherence)
    return dict(
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
        ratio_rms_error_deg=ar.rms_error_deg if ar else None)


def friction_summary(fr: idf.Friction) -> dict:
    """identify.yaml's friction part: the jogs' Coulomb and viscous friction, the Coulomb
    friction each way."""
    return dict(coulomb=fr.coulomb, viscous=fr.viscous, friction_offset=fr.offset,
                coulomb_pos=fr.coulomb + fr.offset, coulomb_neg=fr.coulomb - fr.offset)


def result_of(fit: idf.TwoMassFit, ar, runs: Runs, args, ref: dict, seconds: float) -> dict:
    """identify.yaml: the model, the friction, the run's duration, the creeps' breakaway, and
    with a reference the fit in SI units (analysis.identify.physical_units); plain floats."""
    fr = runs.friction
    result = model_summary(fit, ar, runs, args.band, args.servo_rate) \
        | friction_summary(fr) | dict(seconds=seconds)
    for side, b, coulomb in zip(('pos', 'neg'), runs.creeps, (fr.coulomb + fr.offset,
                                                             fr.coulomb - fr.offset)):
        # a slide that crept without sticking breaks away at its sliding friction
        result[f'breakaway_{side}'] = abs(b.breakaway) if b.breakaway is not None else coulomb
        result[f'stick_slips_{side}'] = b.slips
    if runs.creeps:
        result['creep_velocity'] = args.creep
    si = idf.physical_units(fit, **ref) if ref else {}
    if si:
        fpv = si['force_per_volt']
        result |= dict(force_per_volt=fpv, motor_mass=si['motor_mass'],
                       slide_mass=si['slide_mass'], stiffness_n_per_m=si['stiffness'],
                       coulomb_n=fr.coulomb * fpv, viscous_n_s_per_m=fr.viscous * fpv)
        if args.lead is not None:
            result['motor_inertia_kg_m2'] = si['motor_mass'] * (args.lead / (2 * math.pi)) ** 2
            if args.torque_constant is not None:
                result['amplifier_gain'] = fpv * args.lead / (2 * math.pi) / args.torque_constant
    return {k: (float(v) if isinstance(v, (float, np.floating)) else v)
            for k, v in result.items()}


def write_files(out: pathlib.Path, result: dict, ref: dict, runs: Runs, fit: idf.TwoMassFit,
                ratio, args, log=print) -> pathlib.Path:
    """The report printed, identify.yaml, report.md, response.csv (the measured points, for
    autotune) and bode.png (plotting.bode); returns the plot's path."""
    report = idf.format_report(result, ref, MIN_COHERENCE)
    log(report)
    (out / 'identify.yaml').write_text(yaml.safe_dump(result, sort_keys=False))
    (out / 'report.md').write_text(report + '\n')
    write_response(out / RESPONSE_FILE, runs.motor, runs.load)
    png = out / 'bode.png'
    plot_bode(png, runs.motor, runs.load, fit, min_coherence=MIN_COHERENCE,
              ratio=idf.load_motor_ratio(*ratio) if ratio is not None else None,
              title=f'axis {args.axis}: volts -> motor and load position, loop closed '
                    f'(stepped sine on a {args.velocity * 1e3:g} mm/s base motion)')
    log(f'identify: wrote {out / "identify.yaml"}, {out / RESPONSE_FILE}, {out / "report.md"} '
        f'and {png} '
        f'({result["seconds"]:.1f} s)')
    return png


def identify(axis, args, out: pathlib.Path, log=print) -> dict:
    """The whole measurement on an axis of a ready controller (the module docstring's steps),
    the registers put back after the runs; returns what it found and wrote. Raises
    IdentifyError where the fit does not describe the axis (analysis.identify.doubts)."""
    problem = axis.not_ready()
    if problem:
        raise IdentifyError(problem)
    regs = axis.get(*EXCITATION_REGISTERS)
    lo, hi = args.band
    if not 0 < lo < hi < args.servo_rate / 2:
        raise IdentifyError(f'--band {lo:g},{hi:g}: must be 0 < low < high < '
                            f'{args.servo_rate / 2:g} Hz (half the servo rate)')
    runner = Excitation(axis)
    t0 = time.monotonic()
    loop = axis.get(*LOOP_REGISTERS)
    try:
        runs = run_all(axis, runner, args, loop, log)
    finally:
        axis.set({k: regs[k] for k in EXCITATION_REGISTERS} | loop)
    fit, ar, ratio = fit_model(runs, (lo, hi))
    ref = reference(args)
    result = result_of(fit, ar, runs, args, ref, time.monotonic() - t0)
    png = write_files(out, result, ref, runs, fit, ratio, args, log)
    problems = idf.doubts(fit, result['coherent_fraction'])
    if problems:
        raise IdentifyError('the measurement does not give a model of the axis: '
                            + '; '.join(problems) + f' (look at {png}). A larger --amplitude '
                            'or a longer --dwell where the plot is scattered; on a machine '
                            'whose servo ticks jitter, the lockstep simulation (--spawn '
                            '--lockstep) or a quieter hour')
    return result
