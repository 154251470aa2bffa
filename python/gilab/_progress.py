"""Progress of long calls (references, converge, long renders): tqdm bars when tqdm is
installed, otherwise one plain line per bar on stderr."""

from __future__ import annotations

import contextlib
import sys
import time
from typing import Dict, Iterator

from . import _gilab

try:  # optional
    from tqdm.auto import tqdm as _tqdm
except ImportError:  # pragma: no cover - depends on the environment
    _tqdm = None


class _Reporter:
    """Receives (label, position, total, done) from the library's progress bars."""

    def __init__(self) -> None:
        self._bars: Dict[str, object] = {}
        self._started: Dict[str, float] = {}

    def __call__(self, label: str, position: int, total: int, done: bool) -> None:
        if _tqdm is not None:
            bar = self._bars.get(label)
            if bar is None:
                bar = _tqdm(total=total, desc=label, unit="frame", leave=False)
                self._bars[label] = bar
            bar.n = position
            bar.refresh()
            if done:
                bar.close()
                del self._bars[label]
            return
        start = self._started.setdefault(label, time.perf_counter())
        elapsed = time.perf_counter() - start
        end = "\n" if done else ""
        # One line per bar, rewritten in place (\r), finished with the elapsed time.
        sys.stderr.write(f"\r{label}: {position}/{total} frames, {elapsed:.1f} s{end}")
        sys.stderr.flush()
        if done:
            del self._started[label]


@contextlib.contextmanager
def reporting(enabled: bool = True) -> Iterator[None]:
    """Routes the library's progress bars to tqdm (or a plain line) inside the block."""
    if not enabled:
        yield
        return
    _gilab.set_progress(_Reporter())
    try:
        yield
    finally:
        _gilab.set_progress(None)
