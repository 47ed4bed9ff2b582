import numpy as np
import pytest

from benchmarks.numerical import nearest_neighbour_spacing_deg
from hlr_lab.geometry.sphere import (
    azimuth_elevation,
    direction,
    directions_with_spacing,
    fibonacci_band,
    fibonacci_directions,
)


@pytest.mark.parametrize("spacing", [0.5, 1.0, 2.0])
def test_candidate_spacing_is_at_most_the_request(spacing):
    d = directions_with_spacing(spacing)
    measured = nearest_neighbour_spacing_deg(d)
    assert spacing * 0.8 < measured <= spacing


def test_fibonacci_points_are_uniform():
    d = fibonacci_directions(20000)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    # equal area: the fraction of points in any z-band equals the band's area fraction (Archimedes)
    for lo, hi in [(-1, -0.5), (-0.2, 0.3), (0.9, 1.0)]:
        frac = np.mean((d[:, 2] >= lo) & (d[:, 2] < hi))
        assert frac == pytest.approx((hi - lo) / 2, abs=2e-3)
    az = np.arctan2(d[:, 1], d[:, 0])
    assert np.mean(az > 0) == pytest.approx(0.5, abs=5e-3)


@pytest.mark.parametrize("n", [1, 2, 7, 1000, 222_246])
def test_a_z_band_of_the_lattice_is_one_run_of_indices(n):
    """Every point with z in the band is in the run, and the run holds at most one more at each end."""
    z = fibonacci_directions(n)[:, 2]
    rng = np.random.default_rng(n)
    for lo, hi in [(-1.0, 1.0), (0.2, 0.21), (-1.5, -0.99), (0.999, 2.0), *rng.uniform(-1, 1, (20, 2))]:
        lo, hi = min(lo, hi), max(lo, hi)
        run = fibonacci_band(n, lo, hi)
        inside = np.flatnonzero((z >= lo) & (z <= hi))
        assert np.isin(inside, run).all()
        assert np.all(np.diff(run) == 1)
        assert len(run) <= len(inside) + 2


def test_a_lattice_is_made_once_shared_read_only_and_a_huge_one_is_not_kept():
    """A plan asks for the same lattices each time (the 0.5° one: 222 000 points, 9 ms): up to 2²⁰ points
    they are kept for the next call, read-only so that no caller changes another's; a finer one (a plan at
    --spacing 0.05: 22 M points, 530 MB) is made for its caller alone."""
    from hlr_lab.geometry import sphere

    small = fibonacci_directions(1000)
    assert fibonacci_directions(1000) is small
    assert not small.flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        small[0, 0] = 2.0
    np.testing.assert_array_equal(small, sphere._lattice(1000))
    big = sphere._KEPT_POINTS + 1
    assert fibonacci_directions(big) is not fibonacci_directions(big)


def test_azimuth_elevation_round_trip():
    rng = np.random.default_rng(0)
    az, el = rng.uniform(-np.pi, np.pi, 100), rng.uniform(-1.5, 1.5, 100)
    az2, el2 = azimuth_elevation(direction(az, el))
    np.testing.assert_allclose(az2, az, atol=1e-12)
    np.testing.assert_allclose(el2, el, atol=1e-12)
