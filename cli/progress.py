"""A one-line terminal progress bar: parts of the render done (tiles, or runs of a tile's passes),
samples per second, time left."""
from __future__ import annotations


class ProgressBar:
    def __init__(self, stream, width=28, unit="samples"):
        self.stream, self.width, self.unit = stream, width, unit

    def __call__(self, done, total, samples, seconds):
        frac = done / total
        fill = int(frac * self.width)
        rate = samples / seconds if seconds > 0 else 0.0
        left = seconds * (1 - frac) / frac if frac > 0 else 0.0
        self.stream.write(f"\r[{'#' * fill}{'.' * (self.width - fill)}] {done}/{total} parts  "
                          f"{rate / 1e6:6.2f} M {self.unit}/s  {left:5.1f} s left ")
        self.stream.flush()

    def close(self):
        self.stream.write("\n")
        self.stream.flush()
