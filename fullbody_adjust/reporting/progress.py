"""A console progress line for a run over many frames: stage, percent, frames/s and time left.

Called as ``progress(stage, fraction)`` (the bridge's progress callback). Writes to stderr so stdout stays
free for the result line. On a terminal the line is redrawn in place (carriage return) at most every
``interval`` seconds; in a log (not a terminal) a full line is written at most every ``log_interval``.
"""

import sys
import time


class ConsoleProgress:
    def __init__(self, total_frames, label, *, stream=None, interval=0.2, log_interval=5.0, clock=time.monotonic,
                 unit="frames", per_minute=False):
        self.total_frames = int(total_frames)
        self.unit = unit  # what total_frames counts (a batch counts clips)
        self.per_minute = per_minute
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        isatty = getattr(self.stream, "isatty", None)
        self.in_place = bool(isatty and isatty())
        self.interval = interval if self.in_place else log_interval
        self.clock = clock
        self.started = clock()
        self._last_written = None
        self._last = ("starting", 0.0)
        self._shown = None  # the (stage, fraction) last written
        self._width = 0

    def __call__(self, stage, fraction):
        fraction = min(max(float(fraction), 0.0), 1.0)
        self._last = (stage, fraction)
        now = self.clock()
        if self._last_written is not None and now - self._last_written < self.interval and fraction < 1.0:
            return
        self._last_written = now
        self._shown = self._last
        self._write(self.line(stage, fraction, now - self.started))

    def finish(self):
        """Draw the last state if it was throttled away, and end the line."""
        if self._shown != self._last:
            stage, fraction = self._last
            self._shown = self._last
            self._write(self.line(stage, fraction, self.clock() - self.started))
        if self.in_place and self._shown is not None:
            self.stream.write("\n")
        self.stream.flush()

    def line(self, stage, fraction, elapsed):
        """The text of one progress line (no line ending)."""
        bar_width = 20
        filled = int(round(bar_width * fraction))
        text = f"{self.label} {stage:<8} {100 * fraction:3.0f}% [{'#' * filled}{'.' * (bar_width - filled)}]"
        if fraction > 0.0 and elapsed > 0.0:
            rate = fraction * self.total_frames / elapsed * (60.0 if self.per_minute else 1.0)
            left = elapsed * (1.0 - fraction) / fraction
            text += f" {rate:.1f} {self.unit}/{'min' if self.per_minute else 's'}, {format_seconds(left)} left"
        return text

    def _write(self, text):
        if self.in_place:
            pad = " " * max(0, self._width - len(text))
            self.stream.write("\r" + text + pad)
            self._width = len(text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()


class NoProgress:
    """The same interface, silent (--quiet)."""

    def __call__(self, stage, fraction):
        pass

    def finish(self):
        pass


def format_seconds(seconds):
    """'0:07', '12:03', '1:02:03'."""
    seconds = int(round(max(seconds, 0.0)))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"
