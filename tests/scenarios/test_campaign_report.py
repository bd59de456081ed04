"""The campaign report's box plots (scenarios.campaign_report._boxes) against matplotlib's own Axes.boxplot."""

from __future__ import annotations

import numpy as np


def test_the_light_boxes_draw_what_axes_boxplot_draws():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from h4bench.scenarios.campaign_report import _boxes

    rng = np.random.default_rng(3)
    data = np.exp(rng.normal(size=(9, 5)))
    data[0, 2] = 40.0  # a flier
    fig, (a, b) = plt.subplots(1, 2)
    ref = a.boxplot(data, tick_labels=list("abcde"))
    _boxes(b, data, list("abcde"))
    lines, medians = b.collections[0].get_segments(), b.collections[1].get_segments()
    for j in range(5):
        box = lines[5 * j]
        assert np.allclose(np.unique(box[:, 1]), np.unique(ref["boxes"][j].get_ydata()))  # q1, q3
        assert np.allclose(medians[j][:, 1], ref["medians"][j].get_ydata())
        for w in (0, 1):
            assert np.allclose(lines[5 * j + 1 + w][:, 1], ref["whiskers"][2 * j + w].get_ydata())
            assert np.allclose(lines[5 * j + 3 + w][:, 1], ref["caps"][2 * j + w].get_ydata())
    fliers = np.concatenate([f.get_ydata() for f in ref["fliers"]])
    assert np.allclose(np.sort(b.lines[0].get_ydata()), np.sort(fliers)) and 40.0 in fliers
    assert [t.get_text() for t in b.get_xticklabels()] == list("abcde")
    plt.close(fig)
