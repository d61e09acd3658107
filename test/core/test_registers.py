"""The register table drives the YAML files, the documentation's tables and validation (one
place)."""
import dataclasses
import math
import pathlib

import pytest
import yaml

from motion_ctrl.core import registers as R

REPO = pathlib.Path(__file__).resolve().parents[2]


@pytest.mark.parametrize('path', sorted(R.GENERATED))
def test_params_files_are_generated_from_the_table(path):
    assert (REPO / path).read_text() == R.GENERATED[path](), \
        f'{path} is stale: run python -m motion_ctrl.core.registers --write .'


@pytest.mark.parametrize('path', sorted(R.DOC_BLOCKS))
def test_doc_tables_are_generated_from_the_table(path):
    stale = R.stale_blocks((REPO / path).read_text(), R.DOC_BLOCKS[path])
    assert not stale, (f'{path}: {", ".join(stale)} differ from the register table: run '
                       'python -m motion_ctrl.core.registers --write .')


def test_controller_yaml_holds_every_register_in_ros2_param_load_format():
    data = yaml.safe_load((REPO / 'params/controller.yaml').read_text())
    params = data['controller']['ros__parameters']
    for reg in R.AXIS_REGISTERS:
        key = f'x.{reg.name}'
        if reg.type == 'double_array' and not reg.default:
            continue            # rcl cannot type an empty list: written as a comment
        assert key in params, key
        assert R.CONTROLLER_AXIS[reg.name].check(params[key]) is None
        if reg.type == 'double':
            assert isinstance(params[key], float), f'{key} must be written as a double'


def test_every_register_documents_unit_and_vendor_source():
    physical = {r.name for r in R.AXIS_REGISTERS if r.unit}
    assert {'kp', 'ki', 'kd', 'kvff', 'kaff', 'backlash_distance', 'settling_time'} <= physical
    for r in R.AXIS_REGISTERS:
        text = r.descriptor_text()
        if r.unit:
            assert f'Unit: {r.unit}.' in text
        if r.vendor:
            assert r.vendor in text
    kp = R.CONTROLLER_AXIS['kp']
    assert 'V/m' in kp.descriptor_text() and 'Ixx30' in kp.descriptor_text()


@pytest.mark.parametrize('name,value,fragment', [
    ('kp', -1.0, 'kp'),
    ('kp', math.nan, 'kp'),
    ('kp', 2, 'kp: expected a floating-point number'),
    ('fine_position_tolerance', -1e-6, 'fine_position_tolerance'),
    ('mode', 'position_pd', 'mode: unknown value'),
    ('notch_d1', 2.5, 'notch_d1'),
    ('smoothing', 0.001, 'smoothing'),
    ('leadscrew_table', [0.0, math.inf], 'leadscrew_table[1]'),
])
def test_bad_values_are_refused_with_the_register_named(name, value, fragment):
    reason = R.CONTROLLER_AXIS[name].check(value)
    assert reason and fragment in reason


def test_cross_register_rules():
    v = R.axis_defaults()
    assert R.consistency(v) == []
    bad = v | dict(coarse_position_tolerance=1e-7, fine_position_tolerance=1e-6)
    assert any('coarse_position_tolerance' in r for r in R.consistency(bad))
    bad = v | dict(soft_limit_min=0.2, soft_limit_max=0.1)
    assert any('soft_limit_min' in r for r in R.consistency(bad))
    bad = v | dict(leadscrew_table=[0.0, 1e-6], leadscrew_table_spacing=0.0)
    assert any('leadscrew_table_spacing' in r for r in R.consistency(bad))
    bad = v | dict(notch_n1=0.0, notch_n2=0.0, notch_d1=0.0, notch_d2=1.5)   # unstable poles
    assert any('notch' in r for r in R.consistency(bad))


@pytest.mark.parametrize('name, value, typed', [
    ('leadscrew_table', [], []),                       # YAML [] arrives as a bool array
    ('backlash_table', ['1e-06', '-2.5e-06'], [1e-06, -2.5e-06]),   # rclpy's file loader
    ('backlash_table', '[0.001, 1e-06]', [0.001, 1e-06]),           # ... mixed: one text
    ('backlash_table', '[]', []),
    ('kp', '2e-05', 2e-05),
    ('kp', '20000.0', 20000.0),
])
def test_values_typed_as_declared(name, value, typed):
    """One rule by declared type: the spellings `ros2 param load` / `set` deliver with another
    type become the register's type (then checked as any value)."""
    assert R.CONTROLLER_AXIS[name].as_declared(value) == typed


@pytest.mark.parametrize('name, value', [
    ('kp', '2'), ('kp', 'fast'), ('kp', 2), ('backlash_table', ['1', '2']),
    ('backlash_table', [1, 2]), ('backlash_table', '[0.001, 1]'), ('backlash_table', 'x'),
    ('mode', []), ('correction_max_moves', '2.0'),
])
def test_other_types_are_left_to_be_refused(name, value):
    """Integer spellings stay refused for doubles (2 is not 2.0); nothing else is guessed."""
    assert R.CONTROLLER_AXIS[name].as_declared(value) == value


def test_core_objects_start_with_the_tables_defaults():
    """No default lives outside the register table: each core object built without arguments
    runs the table's values (issue 13; Settling once had its own tolerances, the sampled
    correction 20 moves against the table's 200, the backlash compensation a take-up rate of 0
    against 0.01 m/s)."""
    from motion_ctrl.core.axis import Axis
    from motion_ctrl.core.backlash import BacklashCompensation
    from motion_ctrl.core.dual_loop import SampledCorrection
    from motion_ctrl.core.profile import Profile
    from motion_ctrl.core.registers import CONTROLLER_AXIS
    from motion_ctrl.core.config import (BacklashConfig, CorrectionConfig, LawConfig,
                                         ProfileConfig, SettlingConfig, register_fields)
    from motion_ctrl.core.servo_law import ServoLaw
    from motion_ctrl.core.settling import Settling

    def table(name):
        return CONTROLLER_AXIS[name].default

    s = Settling()
    assert (s.fine_tolerance, s.coarse_tolerance, s.velocity_tolerance, s.settling_time) == (
        table('fine_position_tolerance'), table('coarse_position_tolerance'),
        table('velocity_tolerance'), table('settling_time'))
    c = SampledCorrection()
    assert c.max_moves == table('correction_max_moves') == 200
    assert c.tolerance_counts == round(table('correction_tolerance')
                                       * table('load_counts_per_m')) == 1
    assert ServoLaw().config == LawConfig.of(R.axis_defaults())
    p = Profile()
    assert (p.max_velocity, p.max_acceleration, p.max_jerk, p.smoothing) == (
        table('max_velocity'), table('max_acceleration'), table('max_jerk'), table('smoothing'))
    b = BacklashCompensation()
    assert (b.distance, b.takeup_rate, b.hysteresis) == (
        table('backlash_distance'), table('backlash_takeup_rate'), table('backlash_hysteresis'))
    axis = Axis('x')
    assert axis.r == R.axis_defaults()
    for cfg in (LawConfig, SettlingConfig, CorrectionConfig, ProfileConfig, BacklashConfig):
        registers = register_fields(cfg)
        for f in dataclasses.fields(cfg):
            assert f.name not in registers or f.name in CONTROLLER_AXIS, f'{cfg.__name__}.{f.name}'
            assert f.default is dataclasses.MISSING, f'{cfg.__name__}.{f.name} has a default'


def test_oversized_values_are_refused_by_their_size_not_echoed():
    """The input budgets (MAX_TABLE_ENTRIES, MAX_STRING_CHARS): a 100,000-entry table and a
    1 MB string are refused naming the register, their size and the limit, in a line of a few
    dozen characters (the value is never quoted back); typing a value as declared leaves an
    oversized one as it is. A short bad value is still quoted."""
    table = R.CONTROLLER_AXIS['leadscrew_table']
    big = [1e-6] * 100_000
    assert table.check(big) == (f'leadscrew_table: 100000 entries (at most '
                                f'{R.MAX_TABLE_ENTRIES})')
    assert table.check([1e-6] * R.MAX_TABLE_ENTRIES) is None
    assert table.as_declared(['1e-06'] * 100_000) == ['1e-06'] * 100_000   # left, refused
    megabyte = 'm' * 1_000_000
    for name in ('feedback', 'kp', 'leadscrew_table'):
        reason = R.CONTROLLER_AXIS[name].check(megabyte)
        assert reason == (f'{name}: a 1000000-character string (at most '
                          f'{R.MAX_STRING_CHARS})'), reason
        assert R.CONTROLLER_AXIS[name].as_declared(megabyte) is megabyte
    long_list = R.CONTROLLER_AXIS['kp'].check([0.0] * 100)
    assert long_list == 'kp: expected a floating-point number, got a 100-entry list'
    assert "'motr'" in R.CONTROLLER_AXIS['feedback'].check('motr')
    assert R.CONTROLLER_GLOBAL['axes'].check(['x', 'y' * 5000]).startswith(
        'axes[1]: a 5000-character string')
