"""Ctrl-C interrupts a running estimate and a running experiment with KeyboardInterrupt within
about a second, and the GIL is released while they run."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time

import pytest

import onsager

LONG_ESTIMATE = """
import sys, time, onsager
m = onsager.Model.builtin("double-well")
s = m.simulate(seed=1)
print("started", flush=True)
try:
    onsager.estimate(m, s.t, s.y, method="particle", particles=2_000_000)
except KeyboardInterrupt:
    print("interrupted", time.perf_counter(), flush=True)
    sys.exit(0)
print("finished", flush=True)
"""

LONG_EXPERIMENT = """
import sys, tempfile, time, onsager
print("started", flush=True)
try:
    onsager.run_experiment("double-well-jumps", replicates=200, jobs=1, out=tempfile.mkdtemp(), plots=False)
except KeyboardInterrupt:
    print("interrupted", time.perf_counter(), flush=True)
    sys.exit(0)
print("finished", flush=True)
"""


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a child process")
@pytest.mark.parametrize("script", [LONG_ESTIMATE, LONG_EXPERIMENT], ids=["estimate", "experiment"])
def test_ctrl_c_interrupts_within_a_second(script):
    p = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "started"
    time.sleep(1.0)  # well inside the computation
    sent = time.perf_counter()
    p.send_signal(signal.SIGINT)
    line = p.stdout.readline().split()
    p.wait(timeout=60)
    assert line[0] == "interrupted", line
    assert float(line[1]) - sent < 1.0


def test_the_gil_is_released_during_an_estimate(model):
    sim = model.simulate(seed=1)
    ticks = []
    done = threading.Event()

    def tick():
        while not done.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.005)

    t = threading.Thread(target=tick)
    t.start()
    try:
        onsager.estimate(model, sim.t, sim.y, method="mean-optimal")
    finally:
        done.set()
        t.join()
    assert len(ticks) > 5
