"""The before/after picture of a run, with numpy alone (no Blender, no imaging library; png.py writes it).

Top: skeleton snapshots at a few frames in two orthographic views (FRONT: world X right, Z up; SIDE: world Y
right, Z up, as Blender's Right view), the pose before the run in grey, after in blue, targets as dots in their
effector's colour, obstacle boxes shaded. One scale for every panel, so lengths compare across panels; each
panel is centred on what it shows. Bottom: reach error (or another error the caller names, e.g. a retarget's
contact error) over the frames, one line per effector (solid after, dashed before).

``render(FigureData) -> (H,W,3) uint8``, drawn on a ``canvas.Canvas``. ``Layout`` says where things land (tests use
it to find the pixels they expect).
"""

from dataclasses import dataclass
import math

import numpy as np

from .canvas import Canvas, text_width

INK = (40, 40, 40)
GRID = (225, 225, 225)
FRAME_LINE = (200, 200, 200)
BEFORE_GREY = (170, 170, 170)
AFTER_BLUE = (31, 119, 180)
BOX_FILL = (222, 232, 246)
BOX_EDGE = (130, 160, 205)
EFFECTOR_COLOURS = {"hand.L": (214, 39, 40), "hand.R": (255, 127, 14), "foot.L": (44, 160, 44),
                    "foot.R": (148, 103, 189), "head": (140, 86, 75)}
_MORE_COLOURS = ((227, 119, 194), (188, 189, 34), (23, 190, 207), (127, 127, 127))

# View name, the world axes shown to the right and up.
VIEWS = (("FRONT", 0, 2), ("SIDE", 1, 2))

PANEL_WIDTH, PANEL_HEIGHT = 170, 230
MARGIN = 10
TITLE_HEIGHT = 34
PLOT_HEIGHT = 230
MIN_WIDTH = 620
TARGET_RADIUS = 4
# The error axis spans at least this (scene units): errors at float rounding level then plot as the flat zero
# line they are, not as magnified noise.
MIN_ERROR_AXIS = 1e-3
BONE_WIDTH = 2


@dataclass(frozen=True)
class FigureData:
    """What the picture shows. S snapshot frames, M bone segments, E effectors, K boxes, F frames."""

    title: str
    frames: np.ndarray  # (F,) frame numbers of the error plot
    effectors: tuple  # (E,) names
    error_after: np.ndarray  # (F,E) reach error after the run, NaN: no target
    snapshot_frames: np.ndarray  # (S,) frame numbers of the snapshots
    after_segments: np.ndarray  # (S,M,2,3) bone head and tail, world
    before_segments: np.ndarray = None  # (S,M',2,3)
    targets: np.ndarray = None  # (S,E,3), NaN: no target
    boxes: np.ndarray = None  # (S,K,2,3) min and max corner
    error_before: np.ndarray = None  # (F,E)
    plot_title: str = "REACH ERROR (SCENE UNITS) OVER FRAMES"


def effector_colour(effectors, index):
    name = effectors[index]
    if name in EFFECTOR_COLOURS:
        return EFFECTOR_COLOURS[name]
    return _MORE_COLOURS[index % len(_MORE_COLOURS)]


def lighter(colour, amount=0.5):
    return tuple(int(round(c + (255 - c) * amount)) for c in colour)


def pick_snapshots(count, wanted=4):
    """Indices of up to ``wanted`` rows of ``count``, evenly spread, first and last included."""
    if count <= 0:
        return np.zeros(0, dtype=int)
    return np.unique(np.round(np.linspace(0, count - 1, min(wanted, count))).astype(int))


class Layout:
    """Pixel geometry of the figure for ``data``: image size, panel rectangles, the projection of world points
    into a panel, and the error plot's axes. Pixel coordinates are (x right, y down) floats; a pixel (x, y) is
    image[round(y), round(x)]."""

    def __init__(self, data):
        self.snapshots = len(data.snapshot_frames)
        columns = max(self.snapshots, 1)
        self.width = max(MARGIN + columns * (PANEL_WIDTH + MARGIN), MIN_WIDTH)
        self.panels_top = TITLE_HEIGHT
        self.plot_top = self.panels_top + len(VIEWS) * (PANEL_HEIGHT + MARGIN) + MARGIN
        self.height = self.plot_top + PLOT_HEIGHT + MARGIN
        self._fit(data)
        self._plot_axes(data)

    # --- snapshots ---

    def panel_rect(self, view, s):
        """(x0, y0, x1, y1) of the panel of view ``view`` (index into VIEWS) and snapshot ``s``, inclusive."""
        x0 = MARGIN + s * (PANEL_WIDTH + MARGIN)
        y0 = self.panels_top + view * (PANEL_HEIGHT + MARGIN)
        return x0, y0, x0 + PANEL_WIDTH - 1, y0 + PANEL_HEIGHT - 1

    def project(self, view, s, points):
        """(...,2) pixel positions of world ``points`` (...,3) in panel (view, s)."""
        _, right, up = VIEWS[view]
        points = np.asarray(points, dtype=np.float64)
        x0, y0, x1, y1 = self.panel_rect(view, s)
        cx, cy = (x0 + x1) / 2.0, (y0 + _LABEL_HEIGHT + y1) / 2.0
        centre = self._centres[view, s]
        x = cx + (points[..., right] - centre[0]) * self._scale
        y = cy - (points[..., up] - centre[1]) * self._scale
        return np.stack([x, y], axis=-1)

    def _fit(self, data):
        """One scale for all panels (the largest panel content fits), a centre per panel."""
        self._centres = np.zeros((len(VIEWS), max(self.snapshots, 1), 2))
        spans = [1e-9]
        room_x = PANEL_WIDTH - 2 * _PANEL_PAD
        room_y = PANEL_HEIGHT - 2 * _PANEL_PAD - _LABEL_HEIGHT
        ratios = []
        for s in range(self.snapshots):
            points = _panel_points(data, s)
            for v, (_, right, up) in enumerate(VIEWS):
                if len(points) == 0:
                    continue
                lo = points[:, [right, up]].min(axis=0)
                hi = points[:, [right, up]].max(axis=0)
                self._centres[v, s] = (lo + hi) / 2.0
                span = hi - lo
                spans.append(float(span.max()))
                ratios += [room_x / span[0] if span[0] > 0 else math.inf,
                           room_y / span[1] if span[1] > 0 else math.inf]
        finite = [r for r in ratios if math.isfinite(r)]
        self._scale = min(finite) if finite else 1.0 / max(spans)

    # --- error plot ---

    @property
    def plot_rect(self):
        """(x0, y0, x1, y1) of the error plot's axes box."""
        return (MARGIN + _AXIS_LABEL_WIDTH, self.plot_top + _LEGEND_HEIGHT,
                self.width - MARGIN - 10, self.plot_top + PLOT_HEIGHT - _TICK_LABEL_HEIGHT)

    def plot_xy(self, frames, errors):
        """Pixel positions (...,2) of (frame, error) points in the error plot."""
        x0, y0, x1, y1 = self.plot_rect
        frames = np.asarray(frames, dtype=np.float64)
        errors = np.asarray(errors, dtype=np.float64)
        span = self.frame_max - self.frame_min
        tx = (frames - self.frame_min) / span if span > 0 else np.full(frames.shape, 0.5)
        x = x0 + tx * (x1 - x0)
        y = y1 - errors / self.error_max * (y1 - y0)
        return np.stack(np.broadcast_arrays(x, y), axis=-1)

    def _plot_axes(self, data):
        frames = np.asarray(data.frames, dtype=np.float64)
        self.frame_min = float(frames.min()) if len(frames) else 0.0
        self.frame_max = float(frames.max()) if len(frames) else 1.0
        errors = [np.asarray(data.error_after, dtype=np.float64)]
        if data.error_before is not None:
            errors.append(np.asarray(data.error_before, dtype=np.float64))
        finite = np.concatenate([e[np.isfinite(e)] for e in errors])
        largest = float(finite.max()) if finite.size else 0.0
        self.error_max = nice_ceiling(max(largest, MIN_ERROR_AXIS))


_PANEL_PAD = 8
_LABEL_HEIGHT = 12
_AXIS_LABEL_WIDTH = 58
_LEGEND_HEIGHT = 26
_TICK_LABEL_HEIGHT = 16


def _panel_points(data, s):
    parts = [np.asarray(data.after_segments[s], dtype=np.float64).reshape(-1, 3)]
    if data.before_segments is not None:
        parts.append(np.asarray(data.before_segments[s], dtype=np.float64).reshape(-1, 3))
    if data.targets is not None:
        parts.append(np.asarray(data.targets[s], dtype=np.float64).reshape(-1, 3))
    points = np.concatenate(parts)
    return points[np.all(np.isfinite(points), axis=1)]


NICE_STEPS = (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0)


def nice_ceiling(value):
    """The smallest of NICE_STEPS times a power of ten that is >= value (1 for value <= 0): a round axis end
    whose half is round too."""
    if not (value > 0.0 and math.isfinite(value)):
        return 1.0
    power = 10.0 ** math.floor(math.log10(value))
    for step in NICE_STEPS + (10.0,):
        if step * power >= value * (1.0 - 1e-12):
            return step * power
    return 10.0 * power


# --- the figure ----------------------------------------------------------------------------------------------

def render(data):
    """The figure for ``data`` as an (H,W,3) uint8 image."""
    layout = Layout(data)
    canvas = Canvas(layout.width, layout.height)
    canvas.text(MARGIN, 8, data.title, INK, scale=2)
    key_x = MARGIN
    for label, colour in (("BEFORE", BEFORE_GREY), ("AFTER", AFTER_BLUE)):
        canvas.segments([(key_x, 28)], [(key_x + 14, 28)], colour, width=BONE_WIDTH)
        key_x = canvas.text(key_x + 18, 25, label, INK) + 10
    canvas.dots([(key_x + 3, 28)], 3, INK)
    canvas.text(key_x + 10, 25, "TARGETS (EFFECTOR COLOUR)", INK)
    for s in range(layout.snapshots):
        for v in range(len(VIEWS)):
            _draw_panel(canvas, layout, data, v, s)
    _draw_plot(canvas, layout, data)
    return canvas.pixels


def _draw_panel(canvas, layout, data, v, s):
    rect = layout.panel_rect(v, s)
    x0, y0, x1, y1 = rect
    inner = (x0 + 1, y0 + 1, x1 - 1, y1 - 1)
    _, right, up = VIEWS[v]
    if data.boxes is not None:
        for lo, hi in np.asarray(data.boxes[s], dtype=np.float64):
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
                continue
            a, b = layout.project(v, s, np.stack([lo, hi]))
            canvas.rectangle(a[0], a[1], b[0], b[1], edge=BOX_EDGE, fill=BOX_FILL, clip=inner)
    for segments, colour in ((data.before_segments, BEFORE_GREY), (data.after_segments, AFTER_BLUE)):
        if segments is not None:
            ends = layout.project(v, s, np.asarray(segments[s], dtype=np.float64))
            canvas.segments(ends[:, 0], ends[:, 1], colour, width=BONE_WIDTH, clip=inner)
    if data.targets is not None:
        for e in range(len(data.effectors)):
            canvas.dots(layout.project(v, s, data.targets[s, e]), TARGET_RADIUS,
                        effector_colour(data.effectors, e), clip=inner)
    canvas.rectangle(x0, y0, x1, y1, edge=FRAME_LINE)
    canvas.text(x0 + 4, y0 + 4, f"{VIEWS[v][0]}  F{_frame_label(data.snapshot_frames[s])}", INK)


def _draw_plot(canvas, layout, data):
    x0, y0, x1, y1 = layout.plot_rect
    canvas.text(MARGIN, layout.plot_top + 2, data.plot_title, INK)
    # Legend: one entry per effector with a target, then the line styles.
    after = np.asarray(data.error_after, dtype=np.float64)
    before = None if data.error_before is None else np.asarray(data.error_before, dtype=np.float64)
    shown = [e for e in range(len(data.effectors))
             if np.isfinite(after[:, e]).any() or (before is not None and np.isfinite(before[:, e]).any())]
    lx = MARGIN
    ly = layout.plot_top + 14
    for e in shown:
        colour = effector_colour(data.effectors, e)
        canvas.segments([(lx, ly + 3)], [(lx + 14, ly + 3)], colour, width=2)
        lx = canvas.text(lx + 18, ly, data.effectors[e], INK) + 12
    if before is not None:
        canvas.text(lx + 6, ly, "SOLID: AFTER  DASHED: BEFORE", INK)

    for fraction in (0.0, 0.5, 1.0):  # horizontal grid and y tick labels
        y = y1 - fraction * (y1 - y0)
        canvas.segments([(x0, y)], [(x1, y)], GRID)
        label = _number_label(fraction * layout.error_max)
        canvas.text(x0 - 6 - text_width(label), int(round(y)) - 3, label, INK)
    canvas.rectangle(x0, y0, x1, y1, edge=FRAME_LINE)
    for frame in sorted({layout.frame_min, layout.frame_max}):  # x tick labels
        x = layout.plot_xy(frame, 0.0)[0]
        label = _frame_label(frame)
        canvas.segments([(x, y1)], [(x, y1 + 3)], INK)
        canvas.text(int(round(x - text_width(label) / 2)), y1 + 6, label, INK)

    frames = np.asarray(data.frames, dtype=np.float64)
    clip = (x0, y0 - 2, x1, y1)
    for errors, dash, lighten in ((before, 4, True), (after, 0, False)):
        if errors is None:
            continue
        for e in shown:
            colour = effector_colour(data.effectors, e)
            colour = lighter(colour) if lighten else colour
            xy = layout.plot_xy(frames, errors[:, e])
            if len(frames) == 1:
                canvas.dots(xy, 2, colour, clip=clip)
            else:
                canvas.segments(xy[:-1], xy[1:], colour, width=2, clip=clip, dash=dash)


def _frame_label(frame):
    frame = float(frame)
    return str(int(frame)) if frame.is_integer() else f"{frame:g}"


def _number_label(value):
    return "0" if value == 0 else f"{value:.3g}"
