"""The benchmark command works as doc/performance.md shows it (issue 6): it prints its tables with
numbers in them. Speeds are not asserted (they are the machine's), only that they were measured.
"""
import math
import re
import subprocess
import sys

import pytest


def _row(out: str, prefix: str) -> list[str]:
    rows = [line for line in out.splitlines() if line.startswith(prefix)]
    assert rows, f'no row starting {prefix!r} in:\n{out}'
    return [c.strip() for c in rows[0].strip('|').split('|')]


def _number(cell: str) -> float:
    m = re.match(r'-?[0-9.]+', cell.strip())
    assert m, f'not a number: {cell!r}'
    return float(m.group())


@pytest.mark.timeout(200)
def test_benchmark_prints_core_and_dds_rows(node_env):
    env = dict(node_env)
    # A domain of its own: no node of another test may answer it.
    env['ROS_DOMAIN_ID'] = str((int(env['ROS_DOMAIN_ID']) + 20) % 101 + 1)
    r = subprocess.run([sys.executable, '-m', 'motion_ctrl.tools.benchmark',
                        '--sections', 'core,dds',
                        '--rates', '1000', '--axes', '3', '--seconds', '1'],
                       env=env, capture_output=True, text=True, timeout=190)
    assert r.returncode == 0, r.stderr
    core = _row(r.stdout, '| Axis.update moving')
    assert 0.0 < _number(core[1]) < 1000.0            # µs per tick: measured, finite
    for hardware in ('topics', 'sim'):          # (3 axes: one message carries several)
        dds = _row(r.stdout, f'| {hardware} | 1000 | 3 |')
        assert len(dds) == 10, dds             # every column filled, no error text
        achieved, pct = _number(dds[3]), _number(dds[4])
        assert achieved > 0.0 and math.isclose(pct, achieved / 10.0, abs_tol=0.1)
        p50, p99, jmax = (_number(c) for c in dds[5].split('/'))
        assert p50 <= p99 <= jmax
        # encoder -> tick, command -> plant (sim: no command over DDS)
        for cell in dds[8:] if hardware == 'topics' else dds[8:9]:
            lo, hi = (_number(c) for c in cell.split('/'))
            assert 0.0 <= lo <= hi
