"""silfit.fitting.rig_pipeline's pure parts."""

import math

from silfit.fitting.rig_pipeline import disagreeing_views


def test_a_view_the_fit_cannot_agree_with_is_named():
    names = ["cam0", "cam1", "cam2", "cam3"]
    assert disagreeing_views(names, [1.2, 0.9, 1.5, 1.1]) == []
    (warning,) = disagreeing_views(names, [1.2, 0.9, 38.0, 1.1])
    assert warning.startswith("view cam2: median reprojection error 38.0 px")
    # below the floor a large ratio is noise, not a wrong view; one finite view has nothing to compare with
    assert disagreeing_views(names, [0.5, 0.4, 6.0, 0.5]) == []
    assert disagreeing_views(names, [math.nan, math.nan, 40.0, math.nan]) == []


def test_two_views_that_disagree_are_named():
    # the overall median of two views is their mean, which the worse view never exceeds 4 times:
    # the other view is the reference
    (warning,) = disagreeing_views(["a", "b"], [2.0, 25.0])
    assert warning.startswith("view b: median reprojection error 25.0 px against 2.0 px in the other view")
    assert "either may be the wrong one" in warning
    assert disagreeing_views(["a", "b"], [2.0, 3.0]) == []
