"""The 3-D view's offscreen renderer: the same picture as ``mujoco.Renderer`` (it is made in steps so that the driver's
first compilation runs without the interpreter lock; how long it holds the lock is bench_gui_blocking's to measure)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

pytest.importorskip("devices.sim.physics.world")  # the package sets MUJOCO_GL before mujoco loads

import mujoco  # noqa: E402

from devices.config import load_config  # noqa: E402
from devices.sim.physics import render  # noqa: E402
from devices.sim.physics.backend import scene_from_config  # noqa: E402
from devices.sim.physics.world import PhysicsWorld  # noqa: E402

MOCAP_MARKS = [(np.linspace((0.0, 0.0, 0.05), (0.5, 0.0, 0.05), 48), 0.006, (0.9, 0.2, 0.1, 1.0)),
               (np.linspace((0.0, 0.0, 0.05), (0.5, 0.0, 0.05), 12), 0.011, (0.9, 0.2, 0.1, 0.55))]


@pytest.fixture(scope="module")
def world() -> PhysicsWorld:
    return PhysicsWorld(scene_from_config(load_config(None)))


def _in_own_thread(fn):
    """Run ``fn`` on a thread of its own, as the 3-D tab's render thread does (an OpenGL context is current in the
    thread that made it); returns its result or raises what it raised."""
    out: dict[str, object] = {}

    def run() -> None:
        try:
            out["value"] = fn()
        except BaseException as exc:  # noqa: BLE001 - handed to the test's thread as it was
            out["error"] = exc

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    if "error" in out:
        raise out["error"]  # type: ignore[misc]
    return out["value"]


def _pictures(world: PhysicsWorld) -> tuple[np.ndarray, np.ndarray, int]:
    try:
        ours = render.SceneRenderer(world, 320, 240)
    except render.RenderUnavailable as exc:
        pytest.skip(str(exc))
    try:
        picture = ours.render(MOCAP_MARKS)
        geoms = ours._renderer.scene.ngeom  # noqa: SLF001 - what the marks took of the scene's room
    finally:
        ours.close()
    theirs = mujoco.Renderer(world.model, height=240, width=320)
    try:
        camera = mujoco.MjvCamera()
        camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        camera.distance = render.CAMERA_DISTANCE_M
        camera.azimuth = render.CAMERA_AZIMUTH_DEG
        camera.elevation = render.CAMERA_ELEVATION_DEG
        world.update_scene(theirs, camera)
        render.add_marks(theirs.scene, MOCAP_MARKS)
        reference = theirs.render()
    finally:
        theirs.close()
    return picture, reference, geoms


def test_the_offscreen_renderer_draws_what_mujocos_renderer_draws(world):
    picture, reference, geoms = _in_own_thread(lambda: _pictures(world))
    assert picture.shape == reference.shape == (240, 320, 3)
    assert picture.std() > 1.0  # a scene, not a cleared buffer
    # the same rows (top first), colours and marks: every mark drawn, though the reference has room for 10 000 geoms
    np.testing.assert_array_equal(picture, reference)
    assert geoms < render.MAX_GEOMS


def test_a_renderer_closed_refuses_to_draw(world):
    def made_and_closed() -> render.OffscreenRenderer:
        try:
            renderer = render.OffscreenRenderer(world.model, 120, 160)
        except Exception as exc:  # noqa: BLE001 - no OpenGL here, whatever the back end raises
            pytest.skip(f"no OpenGL rendering here: {exc}")
        renderer.close()
        renderer.close()  # twice is harmless
        return renderer

    renderer = _in_own_thread(made_and_closed)
    with pytest.raises(RuntimeError, match="after close"):
        renderer.render()


def test_a_size_beyond_the_models_offscreen_buffer_is_refused(world):
    with pytest.raises(ValueError, match="offscreen buffer"):
        render.OffscreenRenderer(world.model, 4000, 4000)


def test_a_gl_context_that_cannot_open_leaves_nothing_that_fails_when_collected(monkeypatch):
    """As MuJoCo's GLFW context without an X display: its __init__ raises before it has a ``_context``, and its
    __del__ (free) raised AttributeError later, in whatever test was running when the object was collected."""
    import gc
    import sys

    from devices.sim.physics.render import _new_gl_context

    class NoDisplay:
        def __init__(self, width, height):
            raise RuntimeError("X11: The DISPLAY environment variable is missing")

        def free(self):
            if self._context:
                raise AssertionError("nothing was opened")
            self._context = None

        def __del__(self):
            self.free()

    unraisable: list = []
    monkeypatch.setattr(sys, "unraisablehook", unraisable.append)
    with pytest.raises(RuntimeError, match="DISPLAY"):
        _new_gl_context(NoDisplay, 64, 48)
    gc.collect()
    assert unraisable == []
