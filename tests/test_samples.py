import numpy as np
import pytest

from terrain import DuplicateLocationError, ElevationSamples, InputError


def test_valid_samples_are_read_only():
    s = ElevationSamples([[0, 0], [1, 0], [0, 1]], [1, 2, 3], 0.04, crs=32608)
    assert s.n == 3 and s.z_var.tolist() == [0.04] * 3 and s.crs.to_epsg() == 32608
    with pytest.raises(ValueError):
        s.z[0] = 5.0


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"xy": [[0, np.nan], [1, 0], [0, 1]]}, "xy"),
        ({"z": [1, np.inf, 3]}, "z"),
        ({"z_var": [0.1, -0.2, 0.1]}, "z_var"),
        ({"z": [1, 2]}, "lengths"),
        ({"xy": [0, 1, 2]}, "xy"),
        ({"xy": [[0, 0, 0], [1, 0, 0], [0, 1, 0]]}, "xy"),
        ({"z": ["a", "b", "c"]}, "z"),
    ],
)
def test_bad_input_names_the_field(kwargs, field):
    args = {"xy": [[0, 0], [1, 0], [0, 1]], "z": [1, 2, 3], "z_var": 0.1, **kwargs}
    with pytest.raises(InputError, match=field) as info:
        ElevationSamples(**args)
    assert "Fix:" in str(info.value)


def test_duplicates_consistent_are_merged_by_inverse_variance():
    # Hand computation: z = (1.0/0.01 + 1.1/0.04) / (1/0.01 + 1/0.04) = 1.02, var = 0.008
    s = ElevationSamples([[0, 0], [5, 5], [0, 0]], [1.0, 2.0, 1.1], [0.01, 0.01, 0.04])
    assert s.n == 2 and s.n_merged == 1
    assert s.z[0] == pytest.approx(1.02) and s.z_var[0] == pytest.approx(0.008)
    assert s.z[1] == 2.0


def test_duplicates_conflicting_raise_or_average():
    xy, z, v = [[0, 0], [5, 5], [0, 0]], [1.0, 2.0, 3.0], [0.01, 0.01, 0.01]
    with pytest.raises(DuplicateLocationError, match="duplicates='average'"):
        ElevationSamples(xy, z, v)
    s = ElevationSamples(xy, z, v, duplicates="average")
    # mean 2.0; inverse-variance var 0.005 plus the spread ((1-2)^2 + (3-2)^2) / 2 = 1.0
    assert s.z[0] == pytest.approx(2.0) and s.z_var[0] == pytest.approx(1.005)
    with pytest.raises(DuplicateLocationError):
        ElevationSamples([[0, 0], [0, 0], [1, 1]], [1, 1, 2], duplicates="raise")
    with pytest.raises(DuplicateLocationError):  # exact values disagree: zero variance
        ElevationSamples([[0, 0], [0, 0], [1, 1]], [1, 1.001, 2])
