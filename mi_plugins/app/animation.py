"""Frames side by side with captions: an animated GIF and a PNG contact strip (Pillow).

Images are linear RGB (numpy, H x W x 3), shown as 8-bit sRGB (:func:`to_srgb8`) with
the captions in Pillow's default font. Without Pillow, :func:`available` says why and
the demo skips the animation.
"""
import numpy as np

#: height of a caption line in pixels (Pillow's default bitmap font) and the margin
LINE = 12
PAD = 2


def available():
    """None when Pillow is importable, else the reason it is not."""
    try:
        import PIL.Image  # noqa: F401
        import PIL.ImageDraw  # noqa: F401
    except ImportError as e:
        return "Pillow is not installed (%s): pip install pillow, or the extra mi-plugins[plots]" % e
    return None


def to_srgb8(image):
    """Linear RGB -> 8-bit sRGB (clipped to [0, 1] first)."""
    rgb = np.clip(np.asarray(image)[..., :3], 0, None)
    srgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
    return (np.clip(srgb, 0, 1) * 255 + 0.5).astype(np.uint8)


def panel(image, lines):
    """One image with caption ``lines`` under it (a Pillow RGB image)."""
    from PIL import Image, ImageDraw
    pixels = to_srgb8(image)
    h, w = pixels.shape[:2]
    out = Image.new("RGB", (w, h + PAD + LINE * len(lines)), (0, 0, 0))
    out.paste(Image.fromarray(pixels), (0, 0))
    draw = ImageDraw.Draw(out)
    for k, text in enumerate(lines):
        draw.text((PAD, h + PAD + LINE * k), text, fill=(235, 235, 235))
    return out


def row(panels, gap=PAD):
    """Pillow images side by side (tops aligned) on a black background."""
    from PIL import Image
    out = Image.new("RGB", (sum(p.width for p in panels) + gap * (len(panels) - 1), max(p.height for p in panels)))
    x = 0
    for p in panels:
        out.paste(p, (x, 0))
        x += p.width + gap
    return out


def column(images, gap=PAD):
    """Pillow images one under the other (left aligned)."""
    from PIL import Image
    out = Image.new("RGB", (max(p.width for p in images), sum(p.height for p in images) + gap * (len(images) - 1)))
    y = 0
    for p in images:
        out.paste(p, (0, y))
        y += p.height + gap
    return out


def write_animation(path, columns, seconds_per_frame=0.12):
    """An animated GIF of the frames of every column side by side: ``columns`` is
    [(frames, captions)], each a list per frame (captions: a list of lines per frame);
    an adaptive palette per frame, no dithering (the noise is what it shows). Returns the
    number of frames written."""
    count = len(columns[0][0])
    if any(len(frames) != count or len(captions) != count for frames, captions in columns):
        raise ValueError("animation: every column needs the same number of frames and captions (%d)" % count)
    from PIL import Image
    frames = [row([panel(frames[k], captions[k]) for frames, captions in columns])
              .quantize(colors=255, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE) for k in range(count)]
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=int(1000 * seconds_per_frame), loop=0,
                   optimize=False, disposal=1)
    return count


def write_strip(path, rows, picks):
    """A PNG contact strip: one line per entry of ``rows`` ([(title, frames, captions)]),
    the frames ``picks`` side by side with their captions, the title above each line."""
    from PIL import Image, ImageDraw
    lines = []
    for title, frames, captions in rows:
        body = row([panel(frames[k], captions[k]) for k in picks])
        head = Image.new("RGB", (body.width, LINE + PAD), (0, 0, 0))
        ImageDraw.Draw(head).text((PAD, 1), title, fill=(255, 255, 160))
        lines.append(column([head, body], gap=0))
    column(lines, gap=2 * PAD).save(path)
