"""An RGB image (numpy, uint8) with the few drawing primitives the preview needs: points, lines (thick, dashed,
clipped), dots, rectangles and text in a 5x7 bitmap font."""

import math

import numpy as np

WHITE = (255, 255, 255)


class Canvas:
    """An RGB image with a few drawing primitives; every primitive may be clipped to a rectangle."""

    def __init__(self, width, height, background=WHITE):
        self.pixels = np.empty((height, width, 3), dtype=np.uint8)
        self.pixels[:] = background

    def points(self, xy, colour, clip=None):
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        x = np.round(xy[:, 0]).astype(np.int64)
        y = np.round(xy[:, 1]).astype(np.int64)
        h, w = self.pixels.shape[:2]
        x0, y0, x1, y1 = clip if clip is not None else (0, 0, w - 1, h - 1)
        keep = (x >= max(x0, 0)) & (x <= min(x1, w - 1)) & (y >= max(y0, 0)) & (y <= min(y1, h - 1))
        self.pixels[y[keep], x[keep]] = colour

    def segments(self, a, b, colour, width=1, clip=None, dash=0):
        """Straight lines from each a (N,2) to b (N,2); segments with a non-finite end are skipped. ``dash``:
        on/off length in pixels along x (for the plot's curves), 0 for solid."""
        a = np.asarray(a, dtype=np.float64).reshape(-1, 2)
        b = np.asarray(b, dtype=np.float64).reshape(-1, 2)
        good = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
        a, b = a[good], b[good]
        if len(a) == 0:
            return
        d = b - a
        steps = np.ceil(np.abs(d).max(axis=1)).astype(np.int64) + 1
        which = np.repeat(np.arange(len(a)), steps)
        start = np.repeat(np.cumsum(steps) - steps, steps)
        t = (np.arange(len(which)) - start) / np.maximum(steps[which] - 1, 1)
        xy = a[which] + t[:, None] * d[which]
        if dash:
            xy = xy[(np.floor(xy[:, 0] / dash) % 2) == 0]
        self._thick(xy, colour, width, clip)

    def _thick(self, xy, colour, width, clip):
        offsets = np.arange(width) - (width - 1) // 2
        for ox in offsets:
            for oy in offsets:
                self.points(xy + (ox, oy), colour, clip)

    def dots(self, centres, radius, colour, clip=None):
        r = int(math.ceil(radius))
        grid = np.array([(x, y) for x in range(-r, r + 1) for y in range(-r, r + 1) if x * x + y * y <= radius ** 2],
                        dtype=np.float64)
        centres = np.round(np.asarray(centres, dtype=np.float64).reshape(-1, 2))
        centres = centres[np.all(np.isfinite(centres), axis=1)]
        if len(centres):
            self.points((centres[:, None, :] + grid[None]).reshape(-1, 2), colour, clip)

    def rectangle(self, x0, y0, x1, y1, edge=None, fill=None, clip=None):
        x0, x1 = sorted((int(round(x0)), int(round(x1))))
        y0, y1 = sorted((int(round(y0)), int(round(y1))))
        if clip is not None:
            cx0, cy0, cx1, cy1 = clip
            if x1 < cx0 or x0 > cx1 or y1 < cy0 or y0 > cy1:
                return
        if fill is not None:
            h, w = self.pixels.shape[:2]
            lo_x, lo_y, hi_x, hi_y = clip if clip is not None else (0, 0, w - 1, h - 1)
            fx0, fy0 = max(x0, lo_x, 0), max(y0, lo_y, 0)
            fx1, fy1 = min(x1, hi_x, w - 1), min(y1, hi_y, h - 1)
            if fx0 <= fx1 and fy0 <= fy1:
                self.pixels[fy0:fy1 + 1, fx0:fx1 + 1] = fill
        if edge is not None:
            corners = np.array([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], dtype=np.float64)
            self.segments(corners, np.roll(corners, -1, axis=0), edge, clip=clip)

    def text(self, x, y, string, colour, scale=1):
        """``string`` with its top-left corner at (x, y); lower case is drawn as upper case, unknown
        characters as a box. Returns the x after the last character."""
        for char in str(string):
            glyph = glyph_mask(char)
            if scale > 1:
                glyph = np.kron(glyph, np.ones((scale, scale), dtype=bool))
            ys, xs = np.nonzero(glyph)
            self.points(np.stack([xs + x, ys + y], axis=1), colour)
            x += (GLYPH_WIDTH + 1) * scale
        return x


def text_width(string, scale=1):
    return len(str(string)) * (GLYPH_WIDTH + 1) * scale


GLYPH_WIDTH, GLYPH_HEIGHT = 5, 7

# Each glyph: 7 rows, top first, 5 bits each (most significant bit = leftmost pixel).
_FONT = {
    " ": (0, 0, 0, 0, 0, 0, 0),
    "0": (0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E), "1": (0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E),
    "2": (0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F), "3": (0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E),
    "4": (0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02), "5": (0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E),
    "6": (0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E), "7": (0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08),
    "8": (0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E), "9": (0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C),
    "A": (0x0E, 0x11, 0x11, 0x11, 0x1F, 0x11, 0x11), "B": (0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E),
    "C": (0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E), "D": (0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C),
    "E": (0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F), "F": (0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10),
    "G": (0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F), "H": (0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11),
    "I": (0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E), "J": (0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C),
    "K": (0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11), "L": (0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F),
    "M": (0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11), "N": (0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11),
    "O": (0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E), "P": (0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10),
    "Q": (0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D), "R": (0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11),
    "S": (0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E), "T": (0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04),
    "U": (0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E), "V": (0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04),
    "W": (0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A), "X": (0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11),
    "Y": (0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04), "Z": (0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F),
    ".": (0, 0, 0, 0, 0, 0x0C, 0x0C), ",": (0, 0, 0, 0, 0x0C, 0x04, 0x08), ":": (0, 0x0C, 0x0C, 0, 0x0C, 0x0C, 0),
    "-": (0, 0, 0, 0x1F, 0, 0, 0), "_": (0, 0, 0, 0, 0, 0, 0x1F), "/": (0, 0x01, 0x02, 0x04, 0x08, 0x10, 0),
    "(": (0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02), ")": (0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08),
    "%": (0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03), "=": (0, 0, 0x1F, 0, 0x1F, 0, 0),
    "+": (0, 0x04, 0x04, 0x1F, 0x04, 0x04, 0), "'": (0x04, 0x04, 0x08, 0, 0, 0, 0),
    "<": (0x02, 0x04, 0x08, 0x10, 0x08, 0x04, 0x02), ">": (0x08, 0x04, 0x02, 0x01, 0x02, 0x04, 0x08),
    "[": (0x0E, 0x08, 0x08, 0x08, 0x08, 0x08, 0x0E), "]": (0x0E, 0x02, 0x02, 0x02, 0x02, 0x02, 0x0E),
    "#": (0x0A, 0x0A, 0x1F, 0x0A, 0x1F, 0x0A, 0x0A), "*": (0, 0x04, 0x15, 0x0E, 0x15, 0x04, 0),
}
_UNKNOWN = (0x1F, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1F)


def glyph_mask(char):
    """(7,5) bool pixels of ``char`` (lower case drawn as upper case; unknown characters as a box)."""
    rows = _FONT.get(char.upper(), _UNKNOWN)
    return np.array([[(row >> (GLYPH_WIDTH - 1 - col)) & 1 for col in range(GLYPH_WIDTH)] for row in rows],
                    dtype=bool)
