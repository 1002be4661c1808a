"""Image output: float32 RGB EXR through the OpenEXR package, with string metadata;
PNG and JPEG (sRGB, 8 bit) through Mitsuba's ``mi.Bitmap``."""
import os

import numpy as np

from mi_plugins import __version__

META_PREFIX = "mi_plugins:"
#: output file extensions (lower case) and their formats
FORMATS = {".exr": "exr", ".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg"}


def output_format(path):
    """The format ('exr', 'png' or 'jpeg') that ``path``'s extension asks for; ValueError
    naming the valid extensions otherwise."""
    ext = os.path.splitext(path)[1]
    if ext.lower() not in FORMATS:
        raise ValueError("output '%s': unsupported file extension '%s'; valid extensions: %s"
                         % (path, ext, ", ".join(FORMATS)))
    return FORMATS[ext.lower()]


def check_output(path):
    """Check, before any work, that an image can be written to ``path``: a supported
    extension, an existing writable directory, not a directory itself. Returns the format."""
    fmt = output_format(path)
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.exists(directory):
        raise FileNotFoundError("output '%s': directory '%s' does not exist" % (path, directory))
    if not os.path.isdir(directory):
        raise NotADirectoryError("output '%s': '%s' is not a directory" % (path, directory))
    if os.path.isdir(path):
        raise IsADirectoryError("output '%s' is a directory; give a file name" % path)
    if not os.access(directory, os.W_OK | os.X_OK) or (os.path.exists(path) and not os.access(path, os.W_OK)):
        raise PermissionError("output '%s': no permission to write there" % path)
    return fmt


def save(path, image, metadata=None):
    """Write ``image`` in the format ``path``'s extension asks for (see :data:`FORMATS`):
    EXR with :func:`write`, PNG/JPEG with :func:`write_ldr`."""
    return write(path, image, metadata) if output_format(path) == "exr" else write_ldr(path, image, metadata)


def write(path, image, metadata=None):
    """Write an (H, W, 3) float image as a float32 RGB EXR with ``metadata`` (str -> str)."""
    import OpenEXR
    image = _rgb(image)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for key, value in _metadata(metadata).items():
        header[key] = value
    with OpenEXR.File(header, {"RGB": image}) as f:
        f.write(path)
    return path


def write_ldr(path, image, metadata=None):
    """Write an (H, W, 3) linear float image as an 8-bit sRGB PNG or JPEG (values clamped
    to 0..1 by Mitsuba's conversion); a PNG carries ``metadata`` as text chunks."""
    import mitsuba as mi
    fmt = output_format(path)
    bitmap = mi.Bitmap(_rgb(image), mi.Bitmap.PixelFormat.RGB)
    bitmap = bitmap.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
    if fmt == "png":
        for key, value in _metadata(metadata).items():
            bitmap.metadata()[key] = value
    bitmap.write(path, mi.Bitmap.FileFormat.PNG if fmt == "png" else mi.Bitmap.FileFormat.JPEG)
    return path


def _rgb(image):
    image = np.ascontiguousarray(np.asarray(image, dtype=np.float32))
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError("image: expected shape (H, W, 3), got %s" % (image.shape,))
    return image


def _metadata(metadata):
    meta = {"version": __version__}
    meta.update(metadata or {})
    return {META_PREFIX + key: str(value) for key, value in meta.items()}


def read(path):
    """Return (image (H, W, 3) float32, {metadata key: value}) of an EXR written by :func:`write`."""
    import OpenEXR
    with OpenEXR.File(path) as f:
        header = dict(f.header())
        channels = f.channels()
        if "RGB" in channels:
            image = np.array(channels["RGB"].pixels, dtype=np.float32)
        else:
            image = np.stack([np.array(channels[c].pixels, dtype=np.float32) for c in "RGB"], axis=-1)
    meta = {k[len(META_PREFIX):]: v for k, v in header.items() if isinstance(k, str) and k.startswith(META_PREFIX)}
    return image, meta
