"""Camera frames as Drake's ``lcmt_image_array`` LCM message (the ``drake`` lcmtypes package,
plain Python) and back to RGB arrays.

Decoding accepts what cameras and Drake's ``ImageToLcmImageArrayT`` send: 8-bit RGB, RGBA, BGR,
BGRA or grey, uncompressed, zlib, JPEG or PNG. Anything else raises ``ImageMessageError`` (a
``ValueError``) naming the problem, which the station's watchdog counts as ``malformed``.
"""

from __future__ import annotations

import zlib

import numpy as np
from drake import lcmt_header, lcmt_image, lcmt_image_array

_CHANNELS = {
    lcmt_image.PIXEL_FORMAT_GRAY: 1,
    lcmt_image.PIXEL_FORMAT_RGB: 3,
    lcmt_image.PIXEL_FORMAT_BGR: 3,
    lcmt_image.PIXEL_FORMAT_RGBA: 4,
    lcmt_image.PIXEL_FORMAT_BGRA: 4,
}


class ImageMessageError(ValueError):
    """An ``lcmt_image_array`` that does not hold one decodable 8-bit colour image."""


def encode_image_array(rgb: np.ndarray, utime: int, frame_name: str = "camera") -> lcmt_image_array:
    """One uncompressed 8-bit RGB frame (H, W, 3) as an ``lcmt_image_array`` stamped ``utime``
    [us]."""
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"encode_image_array: need an (H, W, 3) uint8 array, got {rgb.shape}")
    h, w, _ = rgb.shape
    header = lcmt_header()
    header.utime = int(utime)
    header.frame_name = frame_name
    image = lcmt_image()
    image.header = header
    image.width, image.height = w, h
    image.row_stride = 3 * w
    image.data = rgb.tobytes()
    image.size = len(image.data)
    image.bigendian = False
    image.pixel_format = lcmt_image.PIXEL_FORMAT_RGB
    image.channel_type = lcmt_image.CHANNEL_TYPE_UINT8
    image.compression_method = lcmt_image.COMPRESSION_METHOD_NOT_COMPRESSED
    msg = lcmt_image_array()
    msg.header = header
    msg.num_images = 1
    msg.images = [image]
    return msg


def image_utime(msg: lcmt_image_array) -> int:
    """The frame's timestamp [us]: the first image's header, else the array's."""
    if msg.num_images >= 1 and msg.images and msg.images[0].header.utime:
        return int(msg.images[0].header.utime)
    return int(msg.header.utime)


def decode_image(image: lcmt_image) -> np.ndarray:
    """An ``lcmt_image`` as an RGB (H, W, 3) uint8 array; raises ImageMessageError."""
    if image.channel_type != lcmt_image.CHANNEL_TYPE_UINT8:
        raise ImageMessageError(f"channel_type {image.channel_type} is not 8-bit unsigned")
    channels = _CHANNELS.get(image.pixel_format)
    if channels is None:
        raise ImageMessageError(f"pixel_format {image.pixel_format} is not a colour/grey format")
    w, h = int(image.width), int(image.height)
    if w <= 0 or h <= 0:
        raise ImageMessageError(f"image size {w} x {h} is empty")
    data = bytes(image.data)
    method = image.compression_method
    if method == lcmt_image.COMPRESSION_METHOD_NOT_COMPRESSED:
        raw = data
    elif method == lcmt_image.COMPRESSION_METHOD_ZLIB:
        try:
            raw = zlib.decompress(data)
        except zlib.error as exc:
            raise ImageMessageError(f"zlib data does not decompress: {exc}") from exc
    elif method in (lcmt_image.COMPRESSION_METHOD_JPEG, lcmt_image.COMPRESSION_METHOD_PNG):
        import cv2

        decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if decoded is None or decoded.shape[:2] != (h, w):
            raise ImageMessageError(f"compressed data does not decode to {w} x {h}")
        # cv2 decodes colour as BGR(A), whatever the message's pixel_format says.
        return _to_rgb(decoded.reshape(h, w, -1), bgr=decoded.ndim == 3)
    else:
        raise ImageMessageError(f"compression_method {method} is unknown")
    stride = int(image.row_stride) or w * channels
    if stride < w * channels or len(raw) < stride * (h - 1) + w * channels:
        raise ImageMessageError(
            f"{len(raw)} bytes do not hold {w} x {h} x {channels} (row stride {stride})"
        )
    rows = np.frombuffer(raw, np.uint8, count=stride * (h - 1) + w * channels)
    pixels = np.lib.stride_tricks.as_strided(
        rows, shape=(h, w, channels), strides=(stride, channels, 1)
    )
    bgr = image.pixel_format in (lcmt_image.PIXEL_FORMAT_BGR, lcmt_image.PIXEL_FORMAT_BGRA)
    return _to_rgb(pixels, bgr=bgr)


def _to_rgb(pixels: np.ndarray, *, bgr: bool) -> np.ndarray:
    if pixels.shape[2] == 1:
        return np.repeat(pixels, 3, axis=2).copy()
    rgb = pixels[:, :, :3]
    if bgr:
        rgb = rgb[:, :, ::-1]
    return np.ascontiguousarray(rgb)


def decode_image_array(msg: lcmt_image_array) -> np.ndarray:
    """The first colour image of an ``lcmt_image_array`` as RGB (H, W, 3) uint8."""
    if msg.num_images < 1 or not msg.images:
        raise ImageMessageError("the image array holds no image")
    return decode_image(msg.images[0])
