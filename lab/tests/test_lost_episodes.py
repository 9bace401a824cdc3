"""lab/lost_episodes.py's account of a lost episode, on a hand-built record whose answers are known."""

import types

import numpy as np

from lab import lost_episodes  # noqa: E402


def test_describe_reports_start_drift_closest_approach_and_first_step_out_of_view():
    steps, dt = 6, 0.1
    rel = np.zeros((steps, 2, 3))
    rel[:, 1] = [[0.5, 0.0, 4.0], [0.4, 0.0, 3.0], [0.3, 0.0, 0.2], [0.3, 0.1, 0.5], [2.0, 0.0, 1.0], [0, 0, 9.0]]
    target = np.zeros((steps, 2, 3))
    target[:, 1, 1] = 0.08 * np.arange(steps)  # 0.8 m/s along Hill y
    view = np.ones((steps, 2), bool)
    view[4:, 1] = False
    rec = types.SimpleNamespace(rel_pos=rel, target_pos=target, in_view=view)
    stats = types.SimpleNamespace(length=np.array([steps, 5]))
    line = lost_episodes.describe(rec, stats, 1, dt, 1.0)
    assert "length    5" in line and "start [0.5 0.  4. ] m" in line
    assert "drift 0.80 m/s (commands 1.00 m/s)" in line
    assert "closest 0.36 m at step 3" in line  # row 2, |(0.3, 0, 0.2)|; row 5 lies after the episode's end
    assert line.endswith("first out of view: step 5, out for good from step 5")
    view[:, 1] = [True, False, True, True, False, False]
    assert lost_episodes.describe(rec, stats, 1, dt, 1.0).endswith(
        "first out of view: step 2, out for good from step 5"
    )
    view[:, 1] = [True, False, True, True, True, False]  # row 5 lies after the end: in view at step 5, the last
    assert lost_episodes.describe(rec, stats, 1, dt, 1.0).endswith("first out of view: step 2, in view at the end")
    view[:, 1] = True
    assert lost_episodes.describe(rec, stats, 1, dt, 1.0).endswith("first out of view: never")
