"""Camera frames as images: decoding (PNG or JPEG) and lens undistortion.

Everything after this module works on an ideal pinhole image: the frame's
Brown-Conrady coefficients (OpenCV order k1, k2, p1, p2, k3) are removed once
per frame by a remap whose maps are cached per calibration, so undistortion
costs one `cv2.remap`, not one `initUndistortRectifyMap`, per image.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from protocol.errors import ProtocolError
from protocol.messages import CameraFrame


@dataclass(frozen=True, eq=False)
class Frame:
    image: np.ndarray      # BGR uint8, height x width, as the camera took it (distorted)
    meta: CameraFrame      # its estimated pose, intrinsics and calibration; meta.png is not read (may be empty)


READ_PX_PER_CELL = 40.0   # perception reads a frame scaled down to no fewer pixels per cell: twice what markers need
_REDUCED = {1: cv2.IMREAD_COLOR, 2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4,
            8: cv2.IMREAD_REDUCED_COLOR_8}


def reduction(meta: CameraFrame, cell_size_m: float) -> int:
    """How many times smaller than taken perception may read this frame (1, 2, 4 or 8).

    A 12 MP camera over a small floor sees a cell across 150 pixels and more; reading it at a
    quarter of the size costs a sixteenth and still leaves READ_PX_PER_CELL. Only exact
    divisors of the image's size, so the scaled intrinsics stay exact."""
    alt = -float(meta.down_m)
    if not alt > 0 or not cell_size_m > 0:
        return 1
    ppc = min(meta.fx, meta.fy) * cell_size_m / alt
    for r in (8, 4, 2):
        if ppc / r >= READ_PX_PER_CELL and meta.width % r == 0 and meta.height % r == 0:
            return r
    return 1


def scaled(meta: CameraFrame, r: int) -> CameraFrame:
    """The frame's header for its image scaled down r times (pixel centres kept: (c + 0.5) / r - 0.5).
    The lens coefficients act on normalised coordinates and do not change."""
    if r == 1:
        return meta
    return dataclasses.replace(meta, width=meta.width // r, height=meta.height // r, fx=meta.fx / r, fy=meta.fy / r,
                               cx=(meta.cx + 0.5) / r - 0.5, cy=(meta.cy + 0.5) / r - 0.5)


def decode_frame(msg: CameraFrame, reduce: int = 1) -> Frame:
    """CameraFrame (PNG or JPEG bytes) -> Frame, `reduce` times smaller (JPEG decodes straight to
    that size); ProtocolError if the image is not what it claims."""
    image = cv2.imdecode(np.frombuffer(msg.png, np.uint8), _REDUCED[reduce]) if msg.png else None
    if image is None:
        encoding = getattr(msg, "encoding", "png")
        raise ProtocolError(f"CameraFrame: {len(msg.png)} bytes of {encoding} do not decode to an image")
    meta = scaled(msg, reduce)
    if image.shape[:2] != (meta.height, meta.width):
        raise ProtocolError(f"CameraFrame: image is {image.shape[1] * reduce}x{image.shape[0] * reduce}, "
                            f"header says {msg.width}x{msg.height}")
    return Frame(image=image, meta=meta)


def intrinsics(meta: CameraFrame) -> np.ndarray:
    return np.array([[meta.fx, 0.0, meta.cx], [0.0, meta.fy, meta.cy], [0.0, 0.0, 1.0]])


def distortion(meta: CameraFrame) -> tuple[float, float, float, float, float]:
    return (float(getattr(meta, "k1", 0.0)), float(getattr(meta, "k2", 0.0)), float(getattr(meta, "p1", 0.0)),
            float(getattr(meta, "p2", 0.0)), float(getattr(meta, "k3", 0.0)))


@lru_cache(maxsize=8)
def _undistort_maps(width: int, height: int, K: tuple[float, ...], dist: tuple[float, ...]
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    k = np.array(K, np.float64).reshape(3, 3)
    # Same K out as in: the undistorted image keeps the published intrinsics, so the
    # pinhole geometry downstream needs no second camera matrix.
    m1, m2 = cv2.initUndistortRectifyMap(k, np.array(dist), None, k, (width, height), cv2.CV_16SC2)
    # Where the pinhole image has no source pixel (barrel distortion pulls the corners in).
    valid = cv2.remap(np.full((height, width), 255, np.uint8), m1, m2, cv2.INTER_NEAREST,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0
    for a in (m1, m2, valid):
        a.flags.writeable = False
    return m1, m2, valid


def lens_margin_px(meta: CameraFrame) -> int:
    """Pixels from each edge of the undistorted image within which some pixel has no source on
    the sensor (a pincushion lens, or strong barrel terms, leave its corners empty): 0 for a
    pinhole, or for a mild barrel lens whose undistorted image is whole."""
    dist = distortion(meta)
    if not any(dist):
        return 0
    return _lens_margin(meta.width, meta.height, tuple(intrinsics(meta).ravel()), dist)


@lru_cache(maxsize=4)
def _lens_margin(width: int, height: int, K: tuple[float, ...], dist: tuple[float, ...]) -> int:
    # Its own cache: the maps' cache also holds regions' maps, and 12 MP maps cost ~0.1 s to redo.
    _, _, valid = _undistort_maps(width, height, K, dist)
    ys, xs = np.nonzero(~valid)
    if not len(xs):
        return 0
    return int(np.minimum(np.minimum(xs, width - 1 - xs), np.minimum(ys, height - 1 - ys)).max()) + 1


def undistorted(frame: Frame) -> tuple[np.ndarray, np.ndarray | None]:
    """The frame's image as an ideal pinhole camera with the same intrinsics would see it, and
    the mask of its pixels that came from the sensor (None: all of them)."""
    dist = distortion(frame.meta)
    if not any(dist):
        return frame.image, None
    meta = frame.meta
    m1, m2, valid = _undistort_maps(meta.width, meta.height, tuple(intrinsics(meta).ravel()), dist)
    return cv2.remap(frame.image, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), valid


@dataclass(frozen=True, eq=False)
class Pixels:
    """A frame's image as the ideal pinhole camera sees it, in colour and in grey: decoded and
    undistorted once, for whatever reads it (perception, the survey's blur check)."""
    frame: Frame
    image: np.ndarray             # BGR, undistorted
    gray: np.ndarray
    valid: np.ndarray | None      # pixels that came from the sensor (None: all)


def pixels(item: Pixels | Frame | CameraFrame, reduce: int = 1) -> Pixels:
    """Decode (a CameraFrame) and undistort (a Frame), `reduce` times smaller than taken; Pixels
    at that size pass through, larger ones are scaled down."""
    if isinstance(item, Pixels):
        return item if reduce == 1 else _smaller(item, reduce)
    if isinstance(item, CameraFrame):
        frame = decode_frame(item, reduce)
    elif reduce > 1:
        frame = Frame(cv2.resize(item.image, None, fx=1 / reduce, fy=1 / reduce, interpolation=cv2.INTER_AREA),
                      scaled(item.meta, reduce))
    else:
        frame = item
    if frame.image.ndim != 3 or frame.image.shape[:2] != (frame.meta.height, frame.meta.width):
        raise ProtocolError(f"frame at t={frame.meta.time_s:.2f}s: image shape {frame.image.shape} "
                            f"does not match its {frame.meta.width}x{frame.meta.height} header")
    image, valid = undistorted(frame)
    return Pixels(frame, image, cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), valid)


def _smaller(px: Pixels, r: int) -> Pixels:
    """Pixels r times smaller; r divides the image's size (`reduction` offers no other)."""
    def small(a: np.ndarray) -> np.ndarray:
        return cv2.resize(a, None, fx=1 / r, fy=1 / r, interpolation=cv2.INTER_AREA)

    frame = Frame(small(px.frame.image), scaled(px.frame.meta, r))
    valid = None if px.valid is None else small(px.valid.astype(np.uint8) * 255) == 255
    return Pixels(frame, small(px.image), small(px.gray), valid)
