"""Loading raster pictures as grey levels, for every image tracer.

Any failure a user can cause (missing file, not an image, truncated, ...)
becomes one ``InputError`` line that names the file and says what to do; no
decoder traceback ever reaches the user.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from doodlecam.errors import InputError

IMAGE_EXTENSIONS: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".gif")

_FIX = "give a PNG, JPEG, BMP, TIFF or GIF"
# Pictures above this are refused from their header, before any pixel is
# decoded: a plotter cannot draw that much detail, and tracing needs about
# 60 bytes per pixel (a 4000 x 3000 photo stays well under 1 GB).
MAX_PIXELS = 40_000_000


class _TooLarge(Exception):
    def __init__(self, w: int, h: int):
        super().__init__(f"{w} x {h} px")
        self.w, self.h = w, h
_LUMA = np.array([0.2125, 0.7154, 0.0721])  # Rec. 709, as skimage.color.rgb2gray


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split()) or type(e).__name__
    return text if len(text) <= 120 else text[:117] + "..."


def load_gray(path: str | os.PathLike) -> np.ndarray:
    """The picture at ``path`` as a 2-D float64 array in [0, 1] (0 = black).

    Row 0 is the top of the picture. Transparent pixels are composited onto
    white paper; palette, CMYK and 16-bit pictures are converted; of an
    animation or a multi-page file only the first frame is read; the EXIF
    orientation of camera photos is applied.
    """
    name = str(path)
    p = Path(path)
    if not p.exists():
        raise InputError(f"{name}: no such file; check the path")
    if p.is_dir():
        raise InputError(f"{name}: is a folder, not a picture; {_FIX} file")
    try:
        size = p.stat().st_size
        with open(p, "rb"):
            pass
    except OSError as e:
        raise InputError(f"{name}: cannot open ({_one_line(e)}); check its permissions") from None
    if size == 0:
        raise InputError(f"{name}: the file is empty (0 bytes); {_FIX}")

    try:
        array = _read_pillow(p)
    except _TooLarge as e:
        raise InputError(f"{name}: {e.w} x {e.h} px is more than {MAX_PIXELS // 1_000_000} megapixels; "
                         "scale the picture down (a plotter cannot draw that much detail)") from None
    except MemoryError:
        raise InputError(f"{name}: too large to load into memory; scale the picture down") from None
    except Exception as e:  # decoders raise a zoo of types (OSError, SyntaxError, struct.error, ...)
        array = None
        if p.suffix.lower() in (".tif", ".tiff"):  # tifffile reads TIFFs Pillow cannot (float, 16-bit RGB, ...)
            try:
                import imageio.v3 as iio

                shape = iio.improps(p, index=0).shape
                if len(shape) >= 2 and shape[0] * shape[1] > MAX_PIXELS:
                    raise _TooLarge(shape[1], shape[0])
                array = np.asarray(iio.imread(p, index=0))
            except _TooLarge as big:
                raise InputError(f"{name}: {big.w} x {big.h} px is more than {MAX_PIXELS // 1_000_000} megapixels; "
                                 "scale the picture down (a plotter cannot draw that much detail)") from None
            except Exception:
                pass
        if array is None:
            kind = type(e).__name__
            if kind == "UnidentifiedImageError":
                msg = f"not a readable image (cannot identify image file); {_FIX}"
            elif "DecompressionBomb" in kind:  # Pillow refused it from the header already
                import re

                m = re.search(r"\((\d+) pixels\)", str(e))
                size = f"{int(m.group(1)) / 1e6:.0f} megapixels" if m else "the picture"
                msg = (f"{size} is more than {MAX_PIXELS // 1_000_000} megapixels; "
                       "scale the picture down (a plotter cannot draw that much detail)")
            else:
                msg = f"damaged or truncated image ({_one_line(e)}); re-save or re-download it"
            raise InputError(f"{name}: {msg}") from None

    if array.size == 0 or array.ndim < 2 or 0 in array.shape[:2]:
        raise InputError(f"{name}: the picture has no pixels (shape {array.shape}); {_FIX}")
    gray = _to_gray(array)
    if gray is None:
        raise InputError(f"{name}: unsupported pixel layout {array.shape} {array.dtype}; save it as an 8-bit RGB PNG")
    return gray


def _read_pillow(p: Path) -> np.ndarray:
    """Decode the first frame with Pillow, normalising its mode.

    Pillow rather than imageio's default reader because its ``mode`` says
    what the channels mean: a CMYK JPEG and an RGBA PNG both arrive as four
    channels otherwise.
    """
    from PIL import Image, ImageOps

    with Image.open(p) as im:  # reads the header only
        if im.width * im.height > MAX_PIXELS:
            raise _TooLarge(im.width, im.height)
        im.seek(0)  # first frame of a GIF / multi-page TIFF
        im.load()  # decode now, so truncation is caught here
        im = ImageOps.exif_transpose(im)
        mode = im.mode
        if mode == "1":
            im = im.convert("L")
        elif mode in ("L", "RGB") and "transparency" in im.info:  # tRNS colour key
            im = im.convert("LA" if mode == "L" else "RGBA")
        elif not (mode in ("L", "LA", "RGB", "RGBA", "F") or mode.startswith("I")):
            im = im.convert("RGBA")  # P, PA, CMYK, YCbCr, LAB, HSV, RGBa, ...
        return np.array(im)


def _to_gray(a: np.ndarray) -> np.ndarray | None:
    """Scale to [0, 1] by the pixel type, composite alpha on white, weight RGB.

    Works a channel at a time in float32 (exact for 8- and 16-bit values), so
    a 12-megapixel colour photo never becomes a float64 RGB array (~300 MB).
    """
    if a.ndim == 3 and a.shape[2] in (1, 2, 3, 4):
        chans = [a[..., k] for k in range(a.shape[2])]
    elif a.ndim == 2:
        chans = [a]
    else:
        return None
    if a.dtype == bool:
        scale = lambda c: c.astype(np.float32)  # noqa: E731
    elif np.issubdtype(a.dtype, np.integer):
        if a.dtype.itemsize == 1:
            top = 255.0
        elif a.dtype.itemsize == 2 or a.max(initial=0) <= 65535:  # Pillow's 'I' mode holds 16-bit PNGs
            top = 65535.0
        else:
            top = float(np.iinfo(a.dtype).max)
        wide = np.float32 if a.dtype.itemsize <= 2 else np.float64
        scale = lambda c: c.astype(wide) * wide(1.0 / top)  # noqa: E731
    elif np.issubdtype(a.dtype, np.floating):
        v = np.nan_to_num(a.astype(float))
        lo, hi = v.min(), v.max()
        if lo < 0.0 or hi > 1.0:  # not a [0, 1] float picture: stretch it
            v = (v - lo) / (hi - lo) if hi > lo else np.zeros_like(v)
        chans = [v[..., k] for k in range(v.shape[2])] if v.ndim == 3 else [v]
        scale = lambda c: c  # noqa: E731
    else:
        return None
    n = len(chans)
    if n >= 3:
        lum = scale(chans[0]) * float(_LUMA[0])
        lum += scale(chans[1]) * float(_LUMA[1])
        lum += scale(chans[2]) * float(_LUMA[2])
    else:
        lum = scale(chans[0])
    if n in (2, 4):
        alpha = scale(chans[n - 1])
        lum = lum * alpha + (1.0 - alpha)  # onto white paper
    return np.clip(lum, 0.0, 1.0).astype(np.float64, copy=False)


def picture_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """(width, height) in px from the picture's header (EXIF rotation applied), or None if unreadable."""
    try:
        from PIL import Image

        with Image.open(path) as im:
            w, h = im.size
            if im.getexif().get(0x0112, 1) in (5, 6, 7, 8):  # a quarter turn
                w, h = h, w
            return w, h
    except Exception:
        return None


def working_picture(gray: np.ndarray, mm_per_px: float | None, pixel_mm: float,
                    upscale: bool = False) -> tuple[np.ndarray, float]:
    """``gray`` scaled down so that one pixel is drawn ``pixel_mm`` mm, and the factor; with
    ``upscale`` a coarser picture is also scaled up to that grid (bilinear), else left as it is.

    Detail finer than the pen cannot be drawn, and tracer options in px then
    mean the same drawn size whatever the picture's resolution: the same
    photo at 512 and at 4000 px gives nearly the same job. Area-averaged
    (anti-aliased), in float32.
    """
    if not mm_per_px or pixel_mm <= 0 or abs(mm_per_px / pixel_mm - 1) <= 0.05:  # within 5 %: not worth a resample
        return gray, 1.0
    if mm_per_px > pixel_mm and not upscale:
        return gray, 1.0
    from skimage.transform import resize

    k = mm_per_px / pixel_mm
    h, w = gray.shape
    shape = (max(2, round(h * k)), max(2, round(w * k)))
    order = 3 if k > 1 else 1
    out = resize(gray.astype(np.float32), shape, order=order, anti_aliasing=k < 1)
    return np.clip(out, 0.0, 1.0).astype(np.float64), k


def grid_scale(tracer, pixel_mm: float) -> float | None:
    """Pen-width grid px per picture px: the picture's drawn mm per px (``Tracer.mm_per_px``)
    over ``pixel_mm`` (0 = the pen width); None when either is unknown."""
    pixel = pixel_mm if pixel_mm > 0 else (getattr(tracer, "pen_mm", None) or 0.0)
    mm = getattr(tracer, "mm_per_px", None)
    return mm / pixel if mm and pixel > 0 else None


def load_working(path: str | os.PathLike, tracer, pixel_mm: float,
                 upscale: bool = False) -> tuple[np.ndarray, tuple[int, int]]:
    """(working picture, the picture's own (rows, cols)): ``load_gray`` then
    ``working_picture`` at ``pixel_mm`` mm per pixel (0 = the pen width), when
    the pipeline told the tracer its drawn scale (``Tracer.mm_per_px``)."""
    gray = load_gray(path)
    pixel = pixel_mm if pixel_mm > 0 else (getattr(tracer, "pen_mm", None) or 0.0)
    return working_picture(gray, getattr(tracer, "mm_per_px", None), pixel, upscale)[0], gray.shape


def in_picture_px(drawing, shape: tuple[int, int]):
    """A Drawing traced on a working picture, in the picture's own px (pixel centres at integers)."""
    from dataclasses import replace

    ws = (round(drawing.extent[1]), round(drawing.extent[0]))
    if ws == tuple(shape):
        return drawing
    sx, sy = shape[1] / ws[1], shape[0] / ws[0]
    polys = tuple((p + 0.5) * (sx, sy) - 0.5 for p in drawing.polylines)
    return replace(drawing, polylines=polys, extent=(float(shape[1]), float(shape[0])),
                   meta={**drawing.meta, "working_px": (ws[1], ws[0]), "grid_px": float(sx)})


def noise_level(gray: np.ndarray) -> float:
    """Standard deviation of the picture's pixel noise, in grey levels (0-1).

    Immerkaer's fast estimate (1996): the picture convolved with a mask that
    cancels every linear and quadratic tone ramp, summed absolutely. Edges
    and texture leak in a little: clean photos read 0.003-0.018, a clean
    photo with Gaussian noise of 0.03 about 0.035.
    """
    from scipy import ndimage as ndi

    h, w = gray.shape
    if h < 3 or w < 3:
        return 0.0
    mask = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = ndi.convolve(gray.astype(np.float32, copy=False), mask)[1:-1, 1:-1]
    return float(np.sqrt(np.pi / 2) * np.abs(r).sum(dtype=np.float64) / (6 * (w - 2) * (h - 2)))


NOISE_CLEAN, NOISE_HEAVY = 0.02, 0.06  # noise levels: below the first nothing changes ...


def denoise_amount(noise: float) -> float:
    """0 for a clean picture (noise <= NOISE_CLEAN) to 1 for a heavily noisy one (>= NOISE_HEAVY), linear between."""
    return float(np.clip((noise - NOISE_CLEAN) / (NOISE_HEAVY - NOISE_CLEAN), 0.0, 1.0))
