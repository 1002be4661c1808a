"""EXR output through the OpenEXR package, with string metadata."""
import numpy as np

from . import __version__

META_PREFIX = "mi_plugins:"


def write(path, image, metadata=None):
    """Write an (H, W, 3) float image as a float32 RGB EXR with ``metadata`` (str -> str)."""
    import OpenEXR
    image = np.ascontiguousarray(np.asarray(image, dtype=np.float32))
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError("image: expected shape (H, W, 3), got %s" % (image.shape,))
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    meta = {"version": __version__}
    meta.update(metadata or {})
    for key, value in meta.items():
        header[META_PREFIX + key] = str(value)
    with OpenEXR.File(header, {"RGB": image}) as f:
        f.write(path)
    return path


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
