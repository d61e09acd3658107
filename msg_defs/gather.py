"""The record of an excitation run as std_msgs/Float64MultiArray (`<axis>/gather`).

One message per run, published once when the run ends, latched (msg_defs.qos.GATHER_QOS):
rows = servo ticks, columns = motion_ctrl.core.gather.COLUMNS (excitation [V], output [V],
motor [m], load [m], command [m]). The layout is labelled: dim[0] is the ticks, its label
`tick` followed by the run's description as a YAML flow mapping (run number, how it ended,
signal, amplitude, band, duration, base velocity, servo rate); dim[1] is the columns, its
label their names joined by commas. Build and read it here only.
"""
from __future__ import annotations

from array import array

import numpy as np
import yaml
from std_msgs.msg import Float64MultiArray, MultiArrayDimension


def gather_message(records: np.ndarray, columns, meta: dict) -> Float64MultiArray:
    """The message of `records` (ticks × columns)."""
    rows, cols = records.shape
    msg = Float64MultiArray()
    text = yaml.safe_dump(meta, default_flow_style=True, width=1 << 16).strip()
    msg.layout.dim = [MultiArrayDimension(label=f'tick {text}', size=rows, stride=rows * cols),
                      MultiArrayDimension(label=','.join(columns), size=cols, stride=cols)]
    msg.data = array('d', np.ascontiguousarray(records, dtype=float).tobytes())
    return msg


def read_gather(msg) -> tuple[dict, dict]:
    """({column: array}, meta) of a gather message; ValueError if its layout is not one."""
    dims = msg.layout.dim
    if len(dims) != 2 or not dims[0].label.startswith('tick'):
        raise ValueError('not a gather record: expected 2 dimensions, ticks and columns')
    rows, cols = dims[0].size, dims[1].size
    names = dims[1].label.split(',')
    data = np.asarray(msg.data, dtype=float)
    if len(names) != cols or data.size != rows * cols:
        raise ValueError(f'gather record of {data.size} values for {rows} x {cols} '
                         f'({len(names)} column names)')
    meta = yaml.safe_load(dims[0].label[4:].strip() or '{}') or {}
    table = data.reshape(rows, cols)
    return {n: table[:, j].copy() for j, n in enumerate(names)}, meta
