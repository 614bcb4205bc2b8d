"""The camera that records each rendered view: optics, rectification, exposure, sensor, encoding.

Ray casting gives each view's ideal irradiance (float, 0-1). A real stereo rig does not record two
photometrically consistent copies of it, and a photometric loss must see through the differences
(docs/design.md, "The camera"). Each effect below is one param of ``data.synthetic.camera``, in the
order light meets it:

1. **optics blur**: a Gaussian point-spread function of ``blur`` px (at the render width);
2. **vignetting**: the lens passes ``1 - vignetting * rho^2`` of the light at normalised radius
   ``rho`` (1 at the image corner; the second-order term of the cos^4 law), the same pattern in each
   view's own image coordinates, so a surface seen at two image positions gets two gains;
3. **rectification error**: the right view resampled with a vertical offset that varies linearly
   across the image, at most ``rectification`` px (a residual of the rig's calibration);
4. **exposure**: auto-exposure scales the left view to a mean of ``exposure`` (of full scale); the
   right camera's own gain differs from it by a log-normal factor of sigma ``gain_mismatch``;
5. **white balance**: each view's own per-channel gains, log-normal with sigma ``white_balance``;
6. **sensor noise**, drawn per view: Gaussian read noise of ``read_noise`` DN (0-255) and shot noise
   whose variance grows with the signal, ``shot_noise`` DN at full scale; then clipping at full
   scale and 8-bit quantisation;
7. **encoding**: with ``jpeg_quality`` > 0, a JPEG round trip at that quality (KITTI's are PNG).

Every draw comes from the frame's generator, after the scene's, so a frame stays deterministic.
"""

from __future__ import annotations

import cv2
import numpy as np

from msdepth.config.params import CameraConfig
from msdepth.data.imagefile import decode

_LUMA = np.array([0.299, 0.587, 0.114], np.float32)
# Auto-exposure stays within what a camera's shutter and gain can do for a scene.
_MIN_GAIN, _MAX_GAIN = 0.25, 8.0


def _blurred(view: np.ndarray, sigma: float) -> np.ndarray:
    """``view`` through a Gaussian point-spread function of ``sigma`` px (0: unchanged)."""
    if sigma <= 0:
        return view
    return cv2.GaussianBlur(view, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)


def vignette(height: int, width: int, strength: float) -> np.ndarray:
    """The (H, W, 1) fraction of light the lens passes: ``1 - strength * rho^2``, rho = 1 at a corner.

    Example:
        >>> v = vignette(3, 5, 0.3)
        >>> round(float(v[1, 2, 0]), 3), round(float(v[0, 0, 0]), 3)  # centre, corner
        (1.0, 0.7)
    """
    y = (np.arange(height, dtype=np.float32) - (height - 1) / 2.0)[:, None]
    x = (np.arange(width, dtype=np.float32) - (width - 1) / 2.0)[None, :]
    rho2 = (x**2 + y**2) / max(((height - 1) / 2.0) ** 2 + ((width - 1) / 2.0) ** 2, 1e-12)
    return (1.0 - np.float32(strength) * rho2)[..., None].astype(np.float32)


def _misrectified(view: np.ndarray, max_px: float, rng: np.random.Generator) -> np.ndarray:
    """``view`` resampled with a vertical offset ``a + b * x'`` (x' in [-1, 1] across the image), |a| +
    |b| <= ``max_px``: the residual of a rectification (0: unchanged, no draw)."""
    if max_px <= 0:
        return view
    a, b = rng.uniform(-max_px / 2.0, max_px / 2.0, size=2)
    h, w = view.shape[:2]
    xs = np.arange(w, dtype=np.float32)
    tilt = (xs - (w - 1) / 2.0) / max((w - 1) / 2.0, 1.0)
    map_x = np.broadcast_to(xs[None, :], (h, w)).astype(np.float32)
    map_y = (np.arange(h, dtype=np.float32)[:, None] + np.float32(a) + np.float32(b) * tilt[None, :]).astype(
        np.float32
    )
    return cv2.remap(view, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _sensor(view: np.ndarray, cfg: CameraConfig, rng: np.random.Generator) -> np.ndarray:
    """Read and shot noise on the exposed ``view`` (0-1 of full scale), clipped and quantised to uint8."""
    variance = (cfg.read_noise / 255.0) ** 2 + (cfg.shot_noise / 255.0) ** 2 * np.clip(view, 0.0, 1.0)
    noisy = view + rng.standard_normal(view.shape, dtype=np.float32) * np.sqrt(variance).astype(np.float32)
    return (np.clip(noisy, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _encoded(image: np.ndarray, quality: int) -> np.ndarray:
    """``image`` (uint8 RGB) after a JPEG round trip at ``quality`` (0: unchanged)."""
    if quality <= 0:
        return image
    ok, data = cv2.imencode(".jpg", image[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # OpenCV without a JPEG codec: a build problem, not the user's input
        raise RuntimeError("OpenCV could not encode a JPEG")
    return decode(data.tobytes(), cv2.IMREAD_COLOR)[..., ::-1].copy()


def record(
    left: np.ndarray, right: np.ndarray, cfg: CameraConfig, rng: np.random.Generator
) -> list[np.ndarray]:
    """The two views (float32 (H, W, 3) irradiance, 0-1) as the rig's cameras record them: uint8 RGB.

    Example:
        >>> import numpy as np
        >>> from msdepth.config.params import CameraConfig
        >>> view = np.full((8, 12, 3), 0.2, np.float32)
        >>> out = record(view, view, CameraConfig(), np.random.default_rng(0))
        >>> [o.dtype.name for o in out], abs(float(out[0].mean()) / 255 - CameraConfig().exposure) < 0.05
        (['uint8', 'uint8'], True)
    """
    h, w = left.shape[:2]
    lens = vignette(h, w, cfg.vignetting)
    optics = [_blurred(v.astype(np.float32), cfg.blur) * lens for v in (left, right)]
    optics[1] = _misrectified(optics[1], cfg.rectification, rng)
    luma = float((optics[0] @ _LUMA).mean())
    gain = float(np.clip(cfg.exposure / max(luma, 1e-6), _MIN_GAIN, _MAX_GAIN))
    gains = (gain, gain * float(np.exp(rng.normal(0.0, cfg.gain_mismatch))))
    out = []
    for view, view_gain in zip(optics, gains, strict=True):
        balance = np.exp(rng.normal(0.0, cfg.white_balance, size=3)).astype(np.float32)
        exposed = view * np.float32(view_gain) * balance
        out.append(_encoded(_sensor(exposed, cfg, rng), cfg.jpeg_quality))
    return out
