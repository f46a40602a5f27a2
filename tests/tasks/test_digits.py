"""The shipped digit targets: what the design code makes, well formed, starting at the CMP's rest position."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bptsb_ros.tasks import digits


def test_shipped_file_is_what_the_design_code_makes():
    shipped = digits.load_targets()
    made = digits.design_targets()
    assert len(shipped) == len(made) == 10
    for a, b in zip(shipped, made):
        assert a.shape == b.shape
        np.testing.assert_allclose(a, b, atol=1e-6)


@pytest.mark.parametrize("digit", range(10))
def test_target_is_well_formed(digit):
    t = digits.load_targets()[digit]
    dt = digits.DT
    np.testing.assert_array_equal(t[0], [0.0, 0.0])  # every drawing starts at the CMP's rest position
    assert np.isfinite(t).all() and len(t) - 1 >= round(digits.MIN_DURATION / dt)
    # inside the digit box: height 0.5 m (size/8), width 0.6 of it
    extent = t.max(0) - t.min(0)
    assert extent[1] <= digits.HEIGHT + 1e-9 and extent[0] <= 0.6 * digits.HEIGHT + 1e-9 and extent.max() > 0.2
    speed = np.linalg.norm(np.diff(t, axis=0), axis=1) / dt
    # minimum-jerk timing along the stroke: at rest at both ends, peak 1.875 × the mean speed
    assert speed[0] < 0.02 and speed[-1] < 0.02
    length = speed.sum() * dt
    mean = length / ((len(t) - 1) * dt)
    assert speed.max() == pytest.approx(1.875 * mean, rel=0.05)
    # the duration follows the stated rule T = max(T_min, L / v̄) to within a step and the polyline corners
    expected = max(digits.MIN_DURATION, length / digits.MEAN_SPEED)
    assert (len(t) - 1) * dt == pytest.approx(expected, abs=0.02 + 0.05 * expected)


def test_targets_differ_and_longer_digits_take_longer():
    t = digits.load_targets()
    steps = [len(x) - 1 for x in t]
    assert steps[1] < steps[8] and steps[7] < steps[0]  # a 1 or a 7 is quicker than an 8 or a 0
    padded, lengths = digits.padded_targets(t)
    assert padded.shape == (10, max(steps) + 1, 2) and lengths.tolist() == steps
    np.testing.assert_array_equal(padded[1, steps[1]:], np.repeat(t[1][-1:], max(steps) + 1 - steps[1], 0))
    for a in range(10):  # pairwise distinct shapes: mean distance over the common steps above 2 cm
        for b in range(a + 1, 10):
            n = min(steps[a], steps[b]) + 1
            assert np.linalg.norm(t[a][:n] - t[b][:n], axis=1).mean() > 0.02, (a, b)


def test_wrong_time_step_is_refused():
    with pytest.raises(ValueError, match="sampled every 0.01 s"):
        digits.load_targets(dt=0.005)
    doc = json.loads(digits.DATA_FILE.read_text())
    assert set(doc["targets"]) == {str(d) for d in range(10)}
