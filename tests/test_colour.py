import numpy as np

from hlr_lab.geometry.colour import delta_e, linear_to_srgb8, srgb8_to_lab, srgb8_to_linear


def test_srgb8_round_trips_every_code():
    codes = np.arange(256, dtype=np.uint8)
    assert np.array_equal(linear_to_srgb8(srgb8_to_linear(codes)), codes)


def test_reference_lab_values():
    # CIELAB of the sRGB primaries and white (D65), as published by Lindbloom; ±0.05 covers rounding of the matrix
    lab = srgb8_to_lab(np.array([[255, 255, 255], [255, 0, 0], [0, 255, 0], [0, 0, 255]]))
    expected = [[100.0, 0.0, 0.0], [53.24, 80.09, 67.20], [87.73, -86.18, 83.18], [32.30, 79.19, -107.86]]
    np.testing.assert_allclose(lab, expected, atol=0.05)


def test_delta_e_is_euclidean_in_lab():
    assert delta_e(np.array([50.0, 0, 0]), np.array([53.0, 4.0, 0])) == 5.0
