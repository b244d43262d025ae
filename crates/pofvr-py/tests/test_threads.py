"""The GIL is released while rendering and building: two Python threads render at once,
faster than one after the other, and Ctrl-C stops a long POF build."""

import json
import os
import subprocess
import signal
import threading
import time

import numpy as np
import pytest

import pofvr
from conftest import blobs, family


@pytest.fixture(scope="module")
def scene():
    return pofvr.Scene(blobs((96, 96, 96), "float32", 1.0), tf=family(1.0))


def render_pair(scene, together):
    """Two frames of one thread each, in two Python threads at once or one after the
    other: (wall seconds, the frames' own frame_ms summed, the frames)."""
    frames = [None, None]
    start = threading.Barrier(2 if together else 1)

    def work(i):
        start.wait()
        frames[i] = scene.render(view=(30 + 40 * i, 20), size=(384, 384), shade=True, threads=1)

    t0 = time.perf_counter()
    if together:
        ts = [threading.Thread(target=work, args=(i,)) for i in range(2)]
        for t in ts:
            t.start()
        for t in ts:
            t.join()
    else:
        work(0)
        work(1)
    wall = time.perf_counter() - t0
    return wall, sum(f.stats["frame_ms"] for f in frames) / 1e3, frames


def test_two_threads_render_at_once(scene):
    serial = render_pair(scene, together=False)
    # Evidence that does not depend on free cores: the two renders were in flight at the
    # same time, so their own durations add up to more than the wall time of both. With
    # the GIL held during a render they could not overlap (sum <= wall), whatever the
    # round. A frame takes a few tens of milliseconds, so one thread may be scheduled late
    # and find the other nearly done: the best of a few rounds is asserted.
    rounds = []
    for _ in range(5):
        together = render_pair(scene, together=True)
        # The same frames either way.
        for a, b in zip(serial[2], together[2]):
            assert a.rgba_float.tobytes() == b.rgba_float.tobytes()
        rounds.append(together[:2])
        if together[1] > 1.3 * together[0]:
            break
    assert any(s > 1.3 * w for w, s in rounds), rounds


def test_two_threads_render_faster_than_one_after_the_other(scene):
    """Wall time, which needs the CPU for it: on a machine shared with other jobs, the
    process may be given no more than one core's worth, whatever its thread count, and
    then two threads cannot be faster. So each round also measures the CPU time the
    process got while the two threads rendered; the best of several rounds is asserted
    faster (with a margin) when some round got at least 1.5 cores, and the test is
    skipped, with the figures, when none did."""
    if len(os.sched_getaffinity(0)) < 2:
        pytest.skip("one CPU: two threads cannot be faster than one")
    best_serial = best_together = float("inf")
    best_share = 0.0
    for _ in range(6):
        best_serial = min(best_serial, render_pair(scene, together=False)[0])
        c0 = time.process_time()
        wall = render_pair(scene, together=True)[0]
        best_share = max(best_share, (time.process_time() - c0) / wall)
        best_together = min(best_together, wall)
        if best_share >= 1.5 and best_together < 0.8 * best_serial:
            break
    if best_share < 1.5:
        pytest.skip(
            f"the machine gave this process at most {best_share:.2f} cores while two threads "
            f"rendered (wall {best_together:.3f} s together, {best_serial:.3f} s one after the other)"
        )
    assert best_together < 0.8 * best_serial, (best_together, best_serial, best_share)


def test_python_runs_while_a_frame_renders(scene):
    ticks = 0
    done = threading.Event()

    def count():
        nonlocal ticks
        while not done.is_set():
            ticks += 1

    t = threading.Thread(target=count)
    t.start()
    time.sleep(0.01)
    before = ticks
    scene.render(size=(384, 384), shade=True)
    during = ticks - before
    done.set()
    t.join()
    assert during > 1000, f"the counting thread ran {during} times while the frame rendered"


@pytest.fixture
def sigint_raises():
    # Python leaves SIGINT ignored when its parent did (a job started in the background
    # of a non-interactive shell): Ctrl-C would then never reach the build. The test
    # needs the interpreter's own handler, which raises KeyboardInterrupt.
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def test_ctrl_c_stops_a_long_build(sigint_raises):
    # 1651 non-empty bricks at a 24² view grid: a build of many seconds on a few cores.
    scene = pofvr.open("phantom:head:128", brick=8)
    seen = []
    timer = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGINT))
    t0 = time.perf_counter()
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        scene.build_pofs(views=(24, 24), progress=lambda d, t: seen.append((d, t)))
    stopped = time.perf_counter() - t0
    timer.join()
    assert stopped < 6.0, f"the build went on for {stopped:.1f} s after Ctrl-C at 1 s"
    done, total = seen[-1]
    assert 0 < total and done < total, seen[-1]
    assert not scene.has_pofs
    # The scene is as it was: it renders, and a later build completes.
    assert scene.render(size=(16, 16)).rgba.shape == (16, 16, 4)


def test_progress_callback_and_pof_culling():
    scene = pofvr.open("phantom:head:96", brick=8)
    seen = []
    scene.build_pofs(views=(12, 12), progress=lambda d, t: seen.append((d, t)))
    assert scene.has_pofs and seen[-1][0] == seen[-1][1] > 0
    culled = scene.render(view=(0, 0), size=(96, 96), cull="pof", weights=[3, 1])
    assert culled.stats["cull"] == "pof" and culled.stats["bricks"]["culled"] > 0
    whole = scene.render(view=(0, 0), size=(96, 96), whole=True, weights=[3, 1])
    diff = np.abs(culled.rgba_float - whole.rgba_float).max()
    assert diff < 0.05, diff


def test_pofs_saved_by_the_cli_load_and_cull_as_the_cli(cli, tmp_path):
    pof = tmp_path / "head.pof"
    subprocess.run(
        [str(cli), "pof", "build", "phantom:head:64", "--brick", "8", "--views", "8,8",
         "--out", str(pof), "--quiet"],
        check=True, capture_output=True,
    )
    out = tmp_path / "cli"
    subprocess.run(
        [str(cli), "render", "phantom:head:64", "--brick", "8", "--pof", str(pof), "--view", "0,0",
         "--size", "64x64", "--weights", "3,1", "--out", f"{out}.png", "--out-raw", f"{out}.raw",
         "--stats", f"{out}.json", "--quiet"],
        check=True, capture_output=True,
    )
    scene = pofvr.open("phantom:head:64", brick=8)
    scene.load_pofs(pof)
    f = scene.render(view=(0, 0), size=(64, 64), weights=[3, 1])
    assert f.stats["cull"] == "pof"
    assert f.rgba_float.tobytes() == (tmp_path / "cli.raw").read_bytes()
    assert f.stats["bricks"] == json.loads((tmp_path / "cli.json").read_text())["bricks"]
    other = pofvr.open("phantom:head:64", brick=8, step=0.5)
    with pytest.raises(pofvr.InputError, match="built for a different sample step"):
        other.load_pofs(pof)
    assert not other.has_pofs and other.render(size=(8, 8)).width == 8
