"""The report of a bag (`report`, the demo): read it (`bags.reader`), the figures of every move
(`analysis.moves`) and one plot per axis (`plotting.report`)::

    summary = make_report('bag_dir', 'move.png')      # {axis: [MoveSummary, ...]}
    print(format_summary(summary))
"""
from __future__ import annotations

import pathlib

from motion_ctrl.analysis.moves import LOAD_COUNTS_PER_M, OUTPUT_LIMIT, summarize_axis
from motion_ctrl.bags.reader import load_bag
from motion_ctrl.plotting.report import draw_report


def make_report(bag, png=None, *, axes=None, load_counts_per_m=LOAD_COUNTS_PER_M,
                output_limit=OUTPUT_LIMIT, start=None, end=None, namespace=None) -> dict:
    """Read `bag`, draw the figure(s) (when png is given) and return {axis: [MoveSummary]}.

    The summary covers the whole bag; start/end [s] crop the plot only. Raises ReportError.
    """
    data, info = load_bag(bag, axes, namespace)
    summary = {a: summarize_axis(d, load_counts_per_m, output_limit) for a, d in data.items()}
    if png is not None:
        draw_report(data, summary, png, name=pathlib.Path(info['path']).name,
                    counts_per_m=load_counts_per_m, output_limit=output_limit, start=start,
                    end=end)
    return summary
