"""The GIL is released while the GPU works; long calls report progress."""

from __future__ import annotations

import re
import threading
import time


def test_other_threads_run_during_a_render(session):
    ticks = 0
    stop = threading.Event()

    def count():
        nonlocal ticks
        while not stop.is_set():
            ticks += 1
            time.sleep(0.001)

    thread = threading.Thread(target=count)
    thread.start()
    try:
        time.sleep(0.05)
        # The counter's rate with the main thread idle, then while it renders.
        start, before = time.perf_counter(), ticks
        time.sleep(0.3)
        idle_rate = (ticks - before) / (time.perf_counter() - start)
        start, before = time.perf_counter(), ticks
        session.render("reference", frames=16)
        render_rate = (ticks - before) / (time.perf_counter() - start)
    finally:
        stop.set()
        thread.join()
    # A render holding the GIL would stop the counter for its whole length.
    assert render_rate > 0.25 * idle_rate, (render_rate, idle_rate)


def test_progress_plain_line_without_tqdm(session, tmp_path, capsys, monkeypatch):
    import gilab._progress as progress

    monkeypatch.setattr(progress, "_tqdm", None)
    session.reference(spp=2, cache=tmp_path, progress=True)
    err = capsys.readouterr().err
    # One line per bar, rewritten in place, ending with the bar full.
    assert err.startswith("\rreference: 0/") and re.search(r"reference: (\d+)/\1 frames, [0-9.]+ s\n$", err)


def test_progress_to_tqdm_like_bars(session, tmp_path, monkeypatch):
    import gilab._progress as progress

    seen = []

    class FakeBar:
        def __init__(self, total, desc, **_):
            self.total, self.desc, self.n = total, desc, 0
            seen.append(self)

        def refresh(self):
            pass

        def close(self):
            self.closed = True

    monkeypatch.setattr(progress, "_tqdm", FakeBar)
    frame = session.render("reference", frames=3, progress=True)
    assert frame.frames == 3
    assert [(b.desc, b.total, b.n, b.closed) for b in seen] == [("reference", 3, 3, True)]
