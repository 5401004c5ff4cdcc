"""Progress bars on stderr (tqdm): one bar per stage, off when stderr is not a TTY or quiet."""

from __future__ import annotations

import math
import sys


class Progress:
    """Progress of a solve: a counting bar per stage.

    Called as the solvers' callback ``(stage, iteration, step_rad)`` (an iteration counter
    with the current step), and through :meth:`count` ``(stage, done, total)`` by readers
    with a known amount of work (e.g. COLMAP relative-pose estimation, pair by pair).
    Off (and tqdm not even imported: 40 ms of every command's start-up) with ``quiet`` or
    when stderr is not a terminal (pipes, files, CI logs), as tqdm's ``disable=None``.
    Counting stages are in pairs, but ``read`` (the bytes of a large input file read so far,
    :mod:`rotgraph.io.compressed`), in bytes.
    """

    UNITS = {"read": "B"}

    def __init__(self, quiet: bool, mininterval: float = 0.1):
        isatty = getattr(sys.stderr, "isatty", None)
        self.enabled = not quiet and bool(isatty and isatty())
        self.mininterval = mininterval  # seconds between redraws
        self.bar = None
        self.stage: str | None = None

    def _open(self, stage: str, total: int | None, unit: str):
        from tqdm import tqdm

        self.close()
        self.stage = stage
        scale = unit == "B"  # bytes: 12.3MB, 45.6MB/s
        self.bar = tqdm(total=total, desc=f"  {stage}", unit=unit, leave=False, dynamic_ncols=True, mininterval=self.mininterval,
                        unit_scale=scale, unit_divisor=1024 if scale else 1000)
        return self.bar

    def __call__(self, stage: str, iteration: int, step: float) -> None:
        if not self.enabled:
            return
        bar = self.bar if stage == self.stage and self.bar is not None else self._open(stage, None, "it")
        if math.isfinite(step):
            bar.set_postfix_str(f"step {math.degrees(step):.2e} deg", refresh=False)
        bar.update(max(0, iteration - bar.n))

    def count(self, stage: str, done: int, total: int) -> None:
        if not self.enabled:
            return
        bar = self.bar
        if stage != self.stage or bar is None or bar.total != total or done < bar.n:  # another stage, or another file read
            bar = self._open(stage, total, self.UNITS.get(stage, "pair"))
        bar.update(max(0, done - bar.n))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.bar, self.stage = None, None


class BatchProgress:
    """``rotgraph batch``'s view of a run (the ``progress`` callback of
    :func:`rotgraph.pipeline.batch.solve_many`): a bar over problems on stderr (drawn on a
    TTY only), notes and failures as lines above it (always, unless quiet)."""

    def __init__(self, quiet: bool):
        self.enabled = not quiet
        self.failed = 0
        self.bar = None

    def note(self, text: str) -> None:
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.write(text, file=sys.stderr)
        else:
            print(text, file=sys.stderr, flush=True)

    def __call__(self, event: str, value=None) -> None:
        if event == "start":
            if self.enabled and value:
                from tqdm import tqdm

                # disable=None: tqdm draws only when stderr is a terminal.
                self.bar = tqdm(total=value, desc="  problems", unit="problem", disable=None, dynamic_ncols=True)
        elif event == "note":
            self.note(value)
        elif event == "running":
            if self.bar is not None:
                self.bar.refresh()
        elif event == "result":
            if value["status"] == "failed":
                self.failed += 1
                err = value["error"] or ""
                self.note(f"rotgraph batch: failed: {err if value['input'] in err else value['input'] + ': ' + err}")
                if self.bar is not None:
                    self.bar.set_postfix_str(f"{self.failed} failed", refresh=False)
            if self.bar is not None:
                self.bar.update(1)
        elif event == "close":
            if self.bar is not None:
                self.bar.close()
                self.bar = None
