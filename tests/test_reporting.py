"""The report, the progress line and the preview picture (fullbody_adjust.reporting): plain numpy, no bpy."""

import io
import json
import struct
import zlib

from hypothesis import given, settings, strategies as st
import numpy as np
import pytest

from fullbody_adjust.reporting import preview, summary
from fullbody_adjust.reporting.canvas import GLYPH_HEIGHT, GLYPH_WIDTH, WHITE, Canvas, glyph_mask
from fullbody_adjust.reporting.png import encode_png
from fullbody_adjust.reporting.progress import ConsoleProgress, format_seconds

EFFECTORS = ("hand.L", "hand.R", "foot.L", "foot.R", "head")


# --- summary -------------------------------------------------------------------------------------------------

def _outcome(frames=10, seed=0):
    """Arrays shaped like bridge.outcome.Outcome: hand.L reached, hand.R out of reach on frames 6-9, foot.L
    blocked on 2-3 (and limited on 4), foot.R reached, head without target."""
    rng = np.random.default_rng(seed)
    residuals = rng.uniform(0.0, 1e-5, (frames, len(EFFECTORS)))
    residuals[:, 4] = np.nan
    status = np.full((frames, len(EFFECTORS)), "reached", dtype=object)
    status[:, 4] = "unconstrained"
    reasons = np.full(status.shape, "", dtype=object)
    status[6:, 1] = "unreachable"
    residuals[6:, 1] = rng.uniform(0.1, 0.3, frames - 6)
    reasons[6:, 1] = "target beyond the chain's reach"
    status[2:4, 2] = "blocked"
    reasons[2, 2] = "an obstacle kept the chain from the target (stalled after 20 iterations)"
    reasons[3, 2] = "an obstacle kept the chain from the target (stalled after 31 iterations)"
    residuals[2:4, 2] = [0.02, 0.04]
    status[4, 2] = "limited"
    reasons[4, 2] = "joint limits kept the chain from the target"
    residuals[4, 2] = 0.01
    return dict(frames=np.arange(1, frames + 1, dtype=np.float64), effectors=EFFECTORS, residuals=residuals,
                status=status, reasons=reasons)


def test_reach_error_is_split_into_reachable_and_unreachable_targets():
    arrays = _outcome()
    report = summary.summarize(**arrays, joints_inside=np.zeros(10), segments_crossing=np.zeros(10), seconds=2.0)
    residuals, status = arrays["residuals"], arrays["status"]
    hand_r = report["reach_error"]["hand.R"]
    near = residuals[:6, 1]
    assert hand_r["reachable"]["count"] == 6
    assert hand_r["reachable"]["median"] == pytest.approx(np.median(near))
    assert hand_r["reachable"]["p99"] == pytest.approx(np.percentile(near, 99))
    assert hand_r["reachable"]["max"] == pytest.approx(near.max())
    assert hand_r["unreachable"]["max"] == pytest.approx(residuals[6:, 1].max())
    assert "head" not in report["reach_error"]  # no target: not a task
    everything = report["reach_error"]["all"]
    tasks = np.isfinite(residuals) & (status != "unconstrained")
    within = tasks & (status != "unreachable")
    assert everything["reachable"]["count"] == within.sum()
    assert everything["reachable"]["max"] == pytest.approx(residuals[within].max())
    assert everything["unreachable"]["count"] == 4
    assert report["tasks"] == {"total": int(tasks.sum()), "met": int((status == "reached").sum()), "unreachable": 4,
                               "missed_within_reach": 3, "by_status": {"blocked": 2, "limited": 1, "reached": 33,
                                                                       "unreachable": 4}}
    assert report["frames"] == {"start": 1, "end": 10, "count": 10}
    assert report["frames_per_second"] == pytest.approx(10 / 2.0)


def test_frames_not_met_come_as_runs_with_their_reason():
    runs = summary.not_met_runs(**_outcome())
    assert [(r["effector"], r["status"], r["frame_start"], r["frame_end"], r["frames"]) for r in runs] == [
        ("hand.R", "unreachable", 7, 10, 4),
        ("foot.L", "blocked", 3, 4, 2),  # the iteration counts differ, the reason does not
        ("foot.L", "limited", 5, 5, 1),
    ]
    assert runs[1]["reason"].startswith("an obstacle kept the chain from the target")
    assert runs[1]["max_error"] == pytest.approx(0.04)


def test_a_gap_splits_a_run():
    arrays = _outcome()
    arrays["frames"] = np.array([1, 2, 3, 4, 5, 6, 7, 8, 9, 10.5])
    arrays["status"][8, 1] = "reached"
    runs = [r for r in summary.not_met_runs(**arrays) if r["effector"] == "hand.R"]
    assert [(r["frame_start"], r["frame_end"]) for r in runs] == [(7, 8), (10.5, 10.5)]


def test_penetrations_are_counted_over_frames():
    inside = np.array([0, 2, 0, 1, 0, 0, 0, 0, 0, 0])
    crossing = np.array([0, 0, 0, 3, 1, 0, 0, 0, 0, 0])
    arrays = _outcome()
    report = summary.summarize(**arrays, joints_inside=inside, segments_crossing=crossing, seconds=1.0)
    assert report["penetrations"] == {"joints_inside": 3, "segments_crossing": 4, "frames": 3, "first_frame": 2}


def test_report_is_strict_json_with_extra_items_first():
    arrays = _outcome()
    report = summary.summarize(**arrays, joints_inside=np.zeros(10), segments_crossing=np.zeros(10), seconds=0.0,
                               command="adjust", armature="Rig")
    text = summary.to_json(report)
    assert "NaN" not in text and "Infinity" not in text
    loaded = json.loads(text)
    assert list(loaded)[:2] == ["command", "armature"]
    assert loaded["frames_per_second"] is None  # no time measured: unknown, not infinite
    assert loaded["reach_error"]["hand.L"]["unreachable"] == {"count": 0, "median": None, "p99": None, "max": None}
    assert "10 frames" in summary.one_line(loaded) and "3 missed within reach" in summary.one_line(loaded)


def test_summarize_rejects_mismatched_shapes():
    arrays = _outcome()
    arrays["status"] = arrays["status"][:, :3]
    with pytest.raises(ValueError, match="shape"):
        summary.summarize(**arrays, joints_inside=np.zeros(10), segments_crossing=np.zeros(10), seconds=1.0)


# --- progress ------------------------------------------------------------------------------------------------

class _Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_progress_line_gives_rate_and_time_left_and_is_throttled():
    clock, out = _Clock(), io.StringIO()  # StringIO is not a terminal: whole lines, at most every log_interval
    progress = ConsoleProgress(200, "adjust 'Rig'", stream=out, log_interval=5.0, clock=clock)
    clock.now += 4.0
    progress("solving", 0.5)  # 100 frames in 4 s: 25 frames/s, 4 s left
    clock.now += 1.0
    progress("solving", 0.6)  # throttled: 1 s after the last line
    clock.now += 1.0
    progress("writing", 0.75)  # throttled too
    progress.finish()  # writes the last state once
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("adjust 'Rig' solving")
    assert "50%" in lines[0] and "25.0 frames/s" in lines[0] and "0:04 left" in lines[0]
    assert len(lines) == 2 and "writing" in lines[1] and "75%" in lines[1]
    assert f"{0.75 * 200 / 6.0:.1f} frames/s" in lines[1] and "0:02 left" in lines[1]  # 6 s for 3/4


def test_progress_of_a_batch_counts_clips_per_minute():
    clock, out = _Clock(), io.StringIO()
    progress = ConsoleProgress(24, "retarget 24 clips", stream=out, clock=clock, unit="clips", per_minute=True)
    clock.now += 90.0
    progress("6/24", 0.25)  # 6 clips in 90 s: 4 clips a minute, 270 s left
    line = out.getvalue().splitlines()[0]
    assert line.startswith("retarget 24 clips 6/24") and "25%" in line
    assert f"{6 / 90.0 * 60.0:.1f} clips/min" in line and "4:30 left" in line


def test_progress_writes_the_end_once():
    clock, out = _Clock(), io.StringIO()
    progress = ConsoleProgress(10, "run", stream=out, clock=clock)
    clock.now += 1.0
    progress("done", 1.0)
    progress.finish()
    assert out.getvalue().count("100%") == 1


@pytest.mark.parametrize("seconds, text", [(0, "0:00"), (7.4, "0:07"), (59.6, "1:00"), (723, "12:03"),
                                           (3723, "1:02:03")])
def test_format_seconds(seconds, text):
    assert format_seconds(seconds) == text


# --- PNG -----------------------------------------------------------------------------------------------------

def decode_png(data):
    """(H,W,3) uint8 from the bytes encode_png writes (8-bit RGB, filter 0), checking every chunk's CRC."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, chunks = 8, []
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind, payload = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length:pos + 12 + length])
        assert crc == zlib.crc32(kind + payload), kind
        chunks.append((kind, payload))
        pos += 12 + length
    assert [k for k, _ in chunks][0] == b"IHDR" and chunks[-1][0] == b"IEND"
    width, height, depth, colour_type, _, _, interlace = struct.unpack(">IIBBBBB", chunks[0][1])
    assert (depth, colour_type, interlace) == (8, 2, 0)
    raw = zlib.decompress(b"".join(p for k, p in chunks if k == b"IDAT"))
    rows = np.frombuffer(raw, dtype=np.uint8).reshape(height, 1 + 3 * width)
    assert np.all(rows[:, 0] == 0)  # filter type None on every row
    return rows[:, 1:].reshape(height, width, 3)


@settings(deadline=None, max_examples=25)
@given(st.integers(1, 40), st.integers(1, 40), st.integers(0, 2 ** 32 - 1))
def test_png_round_trip(width, height, seed):
    image = np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)
    assert np.array_equal(decode_png(encode_png(image)), image)


def test_png_rejects_a_grey_image():
    with pytest.raises(ValueError, match="H,W,3"):
        encode_png(np.zeros((4, 4), dtype=np.uint8))


# --- the figure ----------------------------------------------------------------------------------------------

def _figure(frames=20):
    """A stick figure whose right forearm swings forward over the frames, a right-hand target at its wrist and
    a box beside it; reach error falling from 0.4 to 0."""
    frame_numbers = np.arange(1, frames + 1, dtype=np.float64)
    shown_rows = preview.pick_snapshots(frames, 3)
    joints = np.array([[0, 0, 1.0], [0, 0, 1.5], [-0.2, 0, 1.45], [-0.45, 0, 1.45], [0.2, 0, 1.45],
                       [0.45, 0, 1.45], [-0.1, 0, 1.0], [-0.1, 0, 0.05], [0.1, 0, 1.0], [0.1, 0, 0.05]])
    bones = np.array([(0, 1), (1, 2), (2, 3), (1, 4), (4, 5), (0, 6), (6, 7), (0, 8), (8, 9)])
    before = np.repeat(joints[bones][None], len(shown_rows), axis=0)  # (S,M,2,3)
    after = before.copy()
    swing = np.linspace(0.0, 0.3, len(shown_rows))
    after[:, 2, 1, 0] = -0.45 + swing / 2
    after[:, 2, 1, 1] = -swing  # the right wrist moves forward (-Y) and in
    targets = np.full((len(shown_rows), len(EFFECTORS), 3), np.nan)
    targets[:, 1] = after[:, 2, 1]
    boxes = np.repeat(np.array([[[0.3, -0.3, 0.5], [0.5, -0.1, 0.8]]])[None], len(shown_rows), axis=0)
    error_after = np.full((frames, len(EFFECTORS)), np.nan)
    error_after[:, 1] = np.linspace(0.4, 0.0, frames)
    error_before = np.full((frames, len(EFFECTORS)), np.nan)
    error_before[:, 1] = 0.4
    return preview.FigureData(title="ADJUST 'RIG'", frames=frame_numbers, effectors=EFFECTORS,
                              error_after=error_after, error_before=error_before,
                              snapshot_frames=frame_numbers[shown_rows], after_segments=after,
                              before_segments=before, targets=targets, boxes=boxes)


def _pixel(image, xy):
    x, y = np.round(xy).astype(int)
    return tuple(int(c) for c in image[y, x])


def test_figure_size_matches_its_layout_and_survives_png():
    data = _figure()
    image = preview.render(data)
    layout = preview.Layout(data)
    assert image.shape == (layout.height, layout.width, 3)
    decoded = decode_png(encode_png(image))
    assert np.array_equal(decoded, image)
    assert _pixel(decoded, (layout.width - 1, layout.height - 1)) == WHITE


def test_figure_draws_bones_targets_and_boxes_where_they_project():
    data = _figure()
    image = decode_png(encode_png(preview.render(data)))
    layout = preview.Layout(data)
    last = len(data.snapshot_frames) - 1
    for view in range(len(preview.VIEWS)):
        for s in range(len(data.snapshot_frames)):
            # The left thigh (after = before): blue drawn over grey, at its midpoint.
            thigh = data.after_segments[s, 7].mean(axis=0)
            assert _pixel(image, layout.project(view, s, thigh)) == preview.AFTER_BLUE
            # The right-hand target: a dot in hand.R's colour.
            target = data.targets[s, 1]
            assert _pixel(image, layout.project(view, s, target)) == preview.EFFECTOR_COLOURS["hand.R"]
    # Where the forearm moved (last snapshot, front view) the old one shows in grey at its middle.
    head, tail = data.before_segments[last, 2]
    old_forearm = head + 0.8 * (tail - head)  # clear of the new forearm and of the target dot
    assert _pixel(image, layout.project(0, last, old_forearm)) == preview.BEFORE_GREY
    # The box is shaded (front view: x 0.3..0.5, z 0.5..0.8; away from every bone).
    centre = data.boxes[0, 0].mean(axis=0)
    assert _pixel(image, layout.project(0, 0, centre)) == preview.BOX_FILL


def test_one_scale_for_every_panel():
    data = _figure()
    layout = preview.Layout(data)
    # The same world length covers the same number of pixels in every panel and view.
    lengths = {round(float(np.linalg.norm(np.diff(layout.project(v, s, [[0, 0, 0], [0, 0, 1.0]]), axis=0))), 6)
               for v in range(len(preview.VIEWS)) for s in range(len(data.snapshot_frames))}
    assert len(lengths) == 1
    # ...and the tallest panel fits: the figure (1.5 units) takes most of a panel's height, not more.
    (pixels_per_unit,) = lengths
    assert 0.5 * preview.PANEL_HEIGHT < 1.5 * pixels_per_unit < preview.PANEL_HEIGHT


def test_error_plot_draws_after_solid_and_before_lighter():
    data = _figure()
    image = preview.render(data)
    layout = preview.Layout(data)
    colour = preview.EFFECTOR_COLOURS["hand.R"]
    assert layout.error_max == preview.nice_ceiling(0.4)
    for row in (3, 10, 16):
        xy = layout.plot_xy(data.frames[row], data.error_after[row, 1])
        assert _pixel(image, xy) == colour
    # The before curve is dashed: along it both its lighter colour and gaps appear.
    x0, _, x1, _ = layout.plot_rect
    y = layout.plot_xy(1.0, 0.4)[1]
    line = [_pixel(image, (x, y)) for x in range(int(x0) + 30, int(x1) - 30)]
    assert preview.lighter(colour) in line
    assert any(p != preview.lighter(colour) for p in line)


def test_effectors_without_target_are_not_plotted():
    data = _figure()
    image = preview.render(data)
    for name in ("hand.L", "foot.L", "foot.R", "head"):
        assert not np.all(image == preview.EFFECTOR_COLOURS[name], axis=-1).any()


def test_a_single_frame_draws_dots():
    data = _figure(frames=1)
    image = preview.render(data)
    layout = preview.Layout(data)
    xy = layout.plot_xy(1.0, data.error_after[0, 1])
    assert _pixel(image, xy) == preview.EFFECTOR_COLOURS["hand.R"]


def test_text_uses_the_bitmap_font():
    canvas = Canvas(40, 12)
    end = canvas.text(2, 3, "a1", preview.INK)
    assert end == 2 + 2 * (GLYPH_WIDTH + 1)
    drawn = np.all(canvas.pixels == preview.INK, axis=-1)
    h, w = GLYPH_HEIGHT, GLYPH_WIDTH
    assert np.array_equal(drawn[3:3 + h, 2:2 + w], glyph_mask("A"))  # lower case drawn as upper case
    assert np.array_equal(drawn[3:3 + h, 8:8 + w], glyph_mask("1"))
    assert drawn.sum() == glyph_mask("A").sum() + glyph_mask("1").sum()


@pytest.mark.parametrize("count, wanted, rows", [(1, 4, [0]), (3, 4, [0, 1, 2]), (48, 4, [0, 16, 31, 47]),
                                                 (10, 2, [0, 9])])
def test_pick_snapshots(count, wanted, rows):
    assert list(preview.pick_snapshots(count, wanted)) == rows


@settings(deadline=None, max_examples=50)
@given(st.floats(1e-9, 1e9))
def test_nice_ceiling_is_the_next_round_number(value):
    nice = preview.nice_ceiling(value)
    assert nice >= value * (1 - 1e-12)
    mantissa = nice / 10.0 ** np.floor(np.log10(nice) + 1e-12)
    assert min(abs(mantissa - m) for m in preview.NICE_STEPS) < 1e-9
    assert nice <= value * 4 / 3 * (1 + 1e-9)  # never more than one step (at most 4/3) above


def test_an_outcome_without_reasons_or_penetrations():
    """A retarget's outcome carries statuses but neither reasons nor penetration counts."""
    arrays = _outcome()
    del arrays["reasons"]

    class Outcome:
        pass

    outcome = Outcome()
    for name, value in arrays.items():
        setattr(outcome, name, value)
    outcome.keyed_bones = ("Hips", "Spine")
    report = summary.summarize_outcome(outcome, 1.0)
    assert report["penetrations"] is None  # not measured, not zero
    assert report["moved_bones"] == ["Hips", "Spine"]
    assert {(r["status"], r["reason"]) for r in report["not_met"]} == {
        ("unreachable", "unreachable"), ("blocked", "blocked"), ("limited", "limited")}
    assert "penetrations" not in summary.one_line(report)
