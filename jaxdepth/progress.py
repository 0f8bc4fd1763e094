"""Progress of a command-line job on stderr: a live line on a terminal, plain timed lines in a log.

On a TTY the line is rewritten in place after every item (``[12/40] 1.8 images/s ETA 16 s  name: done``).
Anywhere else (``nohup``, ``> log 2>&1``, SLURM, Ray workers' logs) a background thread prints one
line every ``interval_s`` seconds (default 5; ``JAXDEPTH_PROGRESS_INTERVAL`` sets it), also before the
first item is done, while the job loads and compiles::

    complete: 0/40 images, starting (loading, compiling), 10 s elapsed
    complete: 12/40 images (30 %), 1.8 images/s, ETA 16 s, 3 skipped, 1 failed, 15 s elapsed

A failed item is printed at once in both modes; ``verbose`` (``-v``) adds one line per item and the
last item's name. The unit names what the job counts: images, sweeps, samples, seeds.

A leaf module (no jaxdepth import): the command lines of ``cli`` and ``research.cli`` use it.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import weakref

DEFAULT_INTERVAL_S = 5.0


def interval_from_env(default: float = DEFAULT_INTERVAL_S) -> float:
    """Seconds between progress lines off a terminal: ``JAXDEPTH_PROGRESS_INTERVAL`` (> 0), else ``default``."""
    try:
        value = float(os.environ.get("JAXDEPTH_PROGRESS_INTERVAL", default))
    except ValueError:
        return default
    return value if value > 0 else default


def _duration(seconds: float) -> str:
    seconds = max(0.0, seconds)
    if seconds < 100:
        return f"{seconds:.0f} s"
    minutes, s = divmod(int(round(seconds)), 60)
    if minutes < 60:
        return f"{minutes} min {s:02d} s"
    return f"{minutes // 60} h {minutes % 60:02d} min"


class Progress:
    """Counts a job's items and reports them on ``stream`` (default stderr); see the module docs.

    Args:
      total: items the job has (done, skipped and failed all count).
      enabled: False: silent (``--quiet``); failures are then reported by the job's summary only.
      unit: what an item is, plural ("images", "sweeps", "samples", "seeds").
      label: the job's name at the start of each line ("complete", "hidden-eval").
      verbose: one line per item, and the last item's name in the timed lines.
      interval_s: seconds between timed lines off a terminal (default :func:`interval_from_env`).
      stream: where to write (default ``sys.stderr``); ``tty`` overrides its ``isatty()``.

    ``update(name, status)`` (status "done", "skipped" or "failed: <message>") is thread-safe: job
    runners call it from their writer threads. ``close()`` stops the timed lines.
    """

    def __init__(self, total: int, *, enabled: bool = True, unit: str = "images", label: str = "",
                 verbose: bool = False, interval_s: float | None = None, stream=None, tty: bool | None = None):
        self.total, self.unit, self.label = int(total), unit, label.strip()
        self.enabled, self.verbose = enabled, verbose
        self.stream = sys.stderr if stream is None else stream
        self.tty = enabled and (self.stream.isatty() if tty is None else tty)
        self.interval_s = interval_from_env() if interval_s is None else float(interval_s)
        self.start = time.perf_counter()
        self.count = self.done = self.skipped = self.failed = 0
        self.last = ""
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._ticker = None
        if enabled and not self.tty:
            # The thread holds the Progress weakly: one that a failed job never closed stops with it.
            self._ticker = threading.Thread(target=_tick, args=(weakref.ref(self), self._closed, self.interval_s),
                                            name="jaxdepth-progress", daemon=True)
            self._ticker.start()

    # ------------------------------------------------------------------ counting

    def update(self, name: str, status: str) -> None:
        with self._lock:
            self.count += 1
            if status.startswith("failed"):
                self.failed += 1
            elif status == "skipped":
                self.skipped += 1
            else:
                self.done += 1
            self.last = name
            if not self.enabled:
                return
            if status.startswith("failed"):
                self._write(("\r\033[K" if self.tty else "") + self._prefix() + f"{name}: {status}\n")
            elif self.tty:
                self._write("\r\033[K" + self._bar() + f"  {name}: {status}")
            elif self.verbose:
                self._write(self._prefix() + f"[{self.count}/{self.total}] {name}: {status}\n")

    def close(self) -> None:
        self._closed.set()
        if self._ticker is not None:
            self._ticker.join(timeout=1.0)
        if self.tty:
            with self._lock:
                self._write("\n")

    # ------------------------------------------------------------------ lines

    def _prefix(self) -> str:
        return f"{self.label}: " if self.label else ""

    def _rate_eta(self, now: float):
        """(items per second over the items computed, not skipped; seconds left) or (None, None)."""
        computed = self.done + self.failed
        elapsed = now - self.start
        if computed == 0 or elapsed <= 0:
            return None, None
        rate = computed / elapsed
        return rate, (self.total - self.count) / rate

    def _bar(self) -> str:
        rate, eta = self._rate_eta(time.perf_counter())
        speed = "" if rate is None else f" {rate:5.1f} {self.unit}/s ETA {_duration(eta)}"
        return f"{self._prefix()}[{self.count}/{self.total}]{speed}"

    def line(self, now: float | None = None) -> str:
        """The timed line (off a terminal) for the counts so far."""
        now = time.perf_counter() if now is None else now
        parts = [f"{self.count}/{self.total} {self.unit}"]
        if self.total:
            parts[0] += f" ({100 * self.count // self.total} %)"
        rate, eta = self._rate_eta(now)
        if self.count == 0:
            parts.append("starting (loading, compiling)")
        elif rate is not None:
            parts += [f"{rate:.2f} {self.unit}/s", f"ETA {_duration(eta)}"]
        if self.skipped:
            parts.append(f"{self.skipped} skipped")
        parts.append(f"{self.failed} failed")
        parts.append(f"{_duration(now - self.start)} elapsed")
        if self.verbose and self.last:
            parts.append(f"last {self.last}")
        return self._prefix() + ", ".join(parts)

    def _timed_line(self) -> None:
        with self._lock:
            if self.count < self.total or self.total == 0:
                self._write(self.line() + "\n")

    def _write(self, text: str) -> None:
        try:
            self.stream.write(text)
            self.stream.flush()
        except (OSError, ValueError):  # a closed or broken stream: progress is not worth failing the job
            pass


def _tick(ref, closed: threading.Event, interval_s: float) -> None:
    """The timed lines of the Progress ``ref()`` until it is closed or gone."""
    while not closed.wait(interval_s):
        progress = ref()
        if progress is None:
            return
        progress._timed_line()
        del progress


def report_summary(summary, *, quiet: bool, t_start: float | None = None, unit: str = "images") -> int:
    """Prints a job's failures, counts and (unless ``quiet``) :func:`timing_line` on stderr; the exit code
    (0 when nothing failed, else 1). ``summary``: a ``RunSummary`` (``done``, ``skipped``, ``failed`` as
    (name, message), ``ok``)."""
    for name, message in summary.failed:
        print(f"FAILED {name}: {message}", file=sys.stderr)
    if not quiet or summary.failed:
        print(f"{len(summary.done)} completed, {len(summary.skipped)} skipped (already done), "
              f"{len(summary.failed)} failed", file=sys.stderr)
    if not quiet and t_start is not None:
        print(timing_line(summary, t_start, time.perf_counter(), unit=unit), file=sys.stderr)
    return 0 if summary.ok else 1


def timing_line(summary, t_start: float, t_end: float, *, unit: str = "images") -> str:
    """Wall time with the rate in ``unit`` per second, start-up (command start -> the job starts: imports,
    JAX, listing) and first-output latency (command start -> first output in place: adds compile-cache
    load and one batch)."""
    total = t_end - t_start
    parts = [f"{total:.1f} s"]
    if summary.done:
        parts[0] += f" ({len(summary.done) / max(total, 1e-9):.1f} {unit}/s)"
    started = getattr(summary, "started_at", None)
    if started is not None:
        parts.append(f"start-up {started - t_start:.2f} s")
    first = getattr(summary, "first_output_at", None)
    if first is not None:
        parts.append(f"first output written at {first - t_start:.2f} s")
    return "time: " + ", ".join(parts)


__all__ = ["Progress", "interval_from_env", "DEFAULT_INTERVAL_S", "report_summary", "timing_line"]
