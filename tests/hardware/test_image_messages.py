"""Camera frames as drake's lcmt_image_array and back."""

import zlib

import cv2
import numpy as np
import pytest
from drake import lcmt_image, lcmt_image_array

from pcvfe_drake.hardware.image_messages import (
    ImageMessageError,
    decode_image_array,
    encode_image_array,
    image_utime,
)


def frame(h=20, w=30):
    rng = np.random.default_rng(3)
    return rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)


def test_round_trip_through_the_wire_format():
    rgb = frame()
    msg = encode_image_array(rgb, utime=123_456)
    back = lcmt_image_array.decode(msg.encode())
    assert image_utime(back) == 123_456
    np.testing.assert_array_equal(decode_image_array(back), rgb)


def _image(
    pixels, pixel_format, compression=lcmt_image.COMPRESSION_METHOD_NOT_COMPRESSED, data=None
):
    h, w = pixels.shape[:2]
    c = 1 if pixels.ndim == 2 else pixels.shape[2]
    im = lcmt_image()
    im.width, im.height, im.row_stride = w, h, w * c
    im.data = data if data is not None else pixels.tobytes()
    im.size = len(im.data)
    im.pixel_format = pixel_format
    im.channel_type = lcmt_image.CHANNEL_TYPE_UINT8
    im.compression_method = compression
    msg = lcmt_image_array()
    msg.num_images, msg.images = 1, [im]
    return msg


def test_bgr_rgba_grey_zlib_and_png_decode_to_the_same_rgb():
    rgb = frame()
    bgr = rgb[:, :, ::-1].copy()
    rgba = np.dstack([rgb, np.full(rgb.shape[:2], 255, np.uint8)])
    cases = [
        _image(bgr, lcmt_image.PIXEL_FORMAT_BGR),
        _image(rgba, lcmt_image.PIXEL_FORMAT_RGBA),
        _image(
            rgb,
            lcmt_image.PIXEL_FORMAT_RGB,
            lcmt_image.COMPRESSION_METHOD_ZLIB,
            zlib.compress(rgb.tobytes()),
        ),  # fmt: skip
        _image(
            rgb,
            lcmt_image.PIXEL_FORMAT_RGB,
            lcmt_image.COMPRESSION_METHOD_PNG,
            cv2.imencode(".png", bgr)[1].tobytes(),
        ),  # fmt: skip
    ]
    for msg in cases:
        np.testing.assert_array_equal(decode_image_array(msg), rgb)
    grey = rgb[:, :, 0].copy()
    out = decode_image_array(_image(grey, lcmt_image.PIXEL_FORMAT_GRAY))
    np.testing.assert_array_equal(out, np.dstack([grey] * 3))


def test_malformed_messages_raise_a_named_error():
    rgb = frame()
    with pytest.raises(ImageMessageError, match="no image"):
        decode_image_array(lcmt_image_array())
    short = _image(rgb, lcmt_image.PIXEL_FORMAT_RGB, data=rgb.tobytes()[:-10])
    with pytest.raises(ImageMessageError, match="do not hold"):
        decode_image_array(short)
    with pytest.raises(ImageMessageError, match="pixel_format"):
        decode_image_array(_image(rgb, lcmt_image.PIXEL_FORMAT_DEPTH))
    bad_zlib = _image(rgb, lcmt_image.PIXEL_FORMAT_RGB, lcmt_image.COMPRESSION_METHOD_ZLIB, b"xx")
    with pytest.raises(ImageMessageError, match="zlib"):
        decode_image_array(bad_zlib)
