"""The worker behind the modal Fit operator: progress flows out, Esc (cancel) stops it."""

from __future__ import annotations

import threading
import time

import pytest

pytestmark = pytest.mark.blender


def test_progress_result_and_cancel(bpy_module):
    from addon.pipeline import BackgroundJob

    def job(progress):
        for i in range(5):
            progress.update(i + 1, 5, f"frame {i}")
        return "state"

    j = BackgroundJob(job).start()
    j.join(5)
    assert j.done and j.result == "state" and j.error is None
    assert j.fraction == 1.0 and j.message == "frame 4"

    started = threading.Event()

    def endless(progress):
        started.set()
        while True:
            progress.update(0, 1, "working")
            time.sleep(0.001)

    j = BackgroundJob(endless).start()
    assert started.wait(5)
    assert not j.done
    j.cancel()
    j.join(5)
    assert j.done and j.cancelled and j.result is None

    def broken(progress):
        raise ValueError("boom")

    j = BackgroundJob(broken).start()
    j.join(5)
    assert isinstance(j.error, ValueError) and not j.cancelled
