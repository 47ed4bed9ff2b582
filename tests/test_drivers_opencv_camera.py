"""The OpenCV camera driver on OpenCV's own image-sequence backend: the same VideoCapture calls, reading,
decoding and control checks as on a V4L2 device (none can be attached here; see the module docstring).
"""

import cv2
import numpy as np
import pytest

from drivers.errors import DeviceError, DeviceFault, DeviceTimeout, LimitError
from drivers.opencv_camera import OpenCVCamera, OpenCVCameraConfig, decode_frame
from drivers.protocols import Camera

RNG = np.random.default_rng(7)


def sequence(tmp_path, frames: list[np.ndarray]) -> str:
    for i, frame in enumerate(frames):
        assert cv2.imwrite(str(tmp_path / f"{i:04d}.png"), frame)
    return str(tmp_path / "%04d.png")


def camera(pattern: str, **kw) -> OpenCVCamera:
    return OpenCVCamera(OpenCVCameraConfig(pattern, backend="images", **kw))


def test_12_bit_values_at_the_top_of_16_bit_words_come_out_as_sensor_values(tmp_path):
    values = [RNG.integers(0, 4096, (6, 8), dtype=np.uint16) for _ in range(2)]
    cam = camera(sequence(tmp_path, [v << 4 for v in values]), bits=12, msb_aligned=True)
    try:
        assert isinstance(cam, Camera)
        for v in values:
            frame = cam.capture()
            assert frame.bits == 12
            assert frame.pixels.shape == (6, 8, 1)
            assert np.array_equal(frame.pixels[..., 0], v)
    finally:
        cam.close()


def test_colour_frames_come_out_rgb(tmp_path):
    rgb = RNG.integers(0, 256, (4, 5, 3), dtype=np.uint8)
    cam = camera(sequence(tmp_path, [rgb[..., ::-1]]))  # files hold BGR, as OpenCV writes them
    try:
        frame = cam.capture()
        assert frame.pixels.dtype == np.uint8
        assert np.array_equal(frame.pixels, rgb)
    finally:
        cam.close()


def test_values_beyond_the_configured_bits_are_refused(tmp_path):
    """12-bit values left at the top of their words, read as if at the bottom: a rig file mistake."""
    cam = camera(sequence(tmp_path, [np.full((3, 3), 4095 << 4, np.uint16)]), bits=12)
    try:
        with pytest.raises(DeviceFault, match=r"values above 12 bits.*msb_aligned"):
            cam.capture()
    finally:
        cam.close()


def test_a_control_the_device_does_not_take_is_a_fault_naming_it(tmp_path):
    """An image sequence has no exposure control, as a camera left in auto mode would not take one."""
    cam = camera(sequence(tmp_path, [np.zeros((3, 3), np.uint16)] * 2), bits=16)
    try:
        cam.set_exposure(0.01)
        with pytest.raises(DeviceFault, match=r"did not take manual exposure mode.*v4l2-ctl"):
            cam.capture()
    finally:
        cam.close()


def test_limits_are_refused_before_the_device_is_asked(tmp_path):
    cam = camera(sequence(tmp_path, [np.zeros((3, 3), np.uint8)]), exposure_range_s=(1e-4, 1.0))
    try:
        with pytest.raises(LimitError, match=r"exposure 2 s is outside"):
            cam.set_exposure(2.0)
        with pytest.raises(LimitError, match=r"gain 30 dB"):
            cam.set_gain(30.0)
        cam.capture()  # nothing pending: the refused values were never sent
    finally:
        cam.close()


def test_no_frame_is_a_timeout_and_a_missing_device_an_error(tmp_path):
    cam = camera(sequence(tmp_path, [np.zeros((3, 3), np.uint8)]))
    try:
        cam.capture()
        with pytest.raises(DeviceTimeout, match="no frame arrived"):
            cam.capture()  # the sequence has ended, as a camera that stops sending
    finally:
        cam.close()
    with pytest.raises(DeviceError, match=r"camera /dev/video97 \(v4l2\): cannot open"):
        OpenCVCamera(OpenCVCameraConfig("/dev/video97"))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_a_raw_v4l2_buffer_is_decoded_into_a_frame(dtype):
    """With RGB conversion off, V4L2 hands over the driver's buffer as one row of bytes (Y8 / Y16 LE)."""
    frame = RNG.integers(0, np.iinfo(dtype).max, (6, 8), dtype=dtype)
    buffer = frame.astype(np.dtype(dtype).newbyteorder("<")).tobytes()
    raw = np.frombuffer(buffer, np.uint8).reshape(1, -1)
    bits = 8 * np.dtype(dtype).itemsize
    pixels = decode_frame(raw, bits=bits, msb_aligned=False, size=(8, 6))
    assert np.array_equal(pixels[..., 0], frame)
    with pytest.raises(ValueError, match="not a 8×5 frame"):
        decode_frame(raw, bits=bits, msb_aligned=False, size=(8, 5))
