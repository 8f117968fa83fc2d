"""Pictures of the physics lab: an offscreen MuJoCo renderer (EGL on Linux) following the robot.

Thread: a renderer owns an OpenGL context made current in the thread that created it; call :meth:`render` from that
thread only (the 3-D tab's render thread). The world is read under its lock (``PhysicsWorld.update_scene``), drawing
happens outside it, so the physics thread is held up only for the scene update.

The renderer is made in the app's process beside the GUI thread, so what it does holding the interpreter lock is time
the window cannot answer. MuJoCo's bindings hold the lock while they make MuJoCo's GL context (``mujoco.MjrContext``);
with software OpenGL (Mesa's llvmpipe, what EGL gives without a GPU) most of that was the driver compiling the code
that builds the ground texture's mipmaps, 50-130 ms. :class:`OffscreenRenderer` has the driver compile it first, through
PyOpenGL, which lets go of the lock in every call (ctypes), so MuJoCo's context is then made in ~10 ms.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any, NamedTuple

import mujoco
import numpy as np

from devices.sim.physics.world import PhysicsWorld

CAMERA_DISTANCE_M = 1.7
CAMERA_AZIMUTH_DEG = 60.0  # from the robot's right, a little from behind; the obstacle is drawn see-through
CAMERA_ELEVATION_DEG = -25.0


class Mark(NamedTuple):
    """Points to draw as spheres: ``points_m`` (N, 3) in the world's frame (NaN rows left out), ``radius_m``,
    ``rgba`` (four numbers 0…1). A plain 3-tuple does as well (the app passes those: it does not import the
    simulated lab)."""

    points_m: np.ndarray
    radius_m: float
    rgba: tuple[float, float, float, float]


def add_marks(scene: mujoco.MjvScene, marks: Sequence[Mark]) -> int:
    """Append ``marks`` to a scene already updated from the world (as many as it has room for); returns how many
    spheres were added."""
    added = 0
    eye = np.eye(3).reshape(-1)
    for points_m, radius_m, colour in marks:
        points = np.asarray(points_m, dtype=float).reshape(-1, 3)
        size = np.array([radius_m, 0.0, 0.0])
        rgba = np.asarray(colour, dtype=np.float32)
        for point in points[np.isfinite(points).all(axis=1)]:
            if scene.ngeom >= scene.maxgeom:
                return added
            mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_SPHERE, size, point, eye, rgba)
            scene.ngeom += 1
            added += 1
    return added


class RenderUnavailable(RuntimeError):
    """No OpenGL rendering here (no EGL/OSMesa/display); the message says why."""


# Room for the scene's geoms (27 for the robot on the paper's terrain) and the motion capture's marks (≤ 60). Each
# slot is allocated when the renderer is made, holding the interpreter lock: mujoco.Renderer's default of 10 000
# took ~18 ms, 1 000 ~7 ms.
MAX_GEOMS = 1000
WARM_TEXTURE_PX = 256  # as the ground's checker texture (devices/sim/physics/model.py)


def _new_gl_context(kind: Any, width: int, height: int) -> Any:
    """``kind(width, height)`` (a MuJoCo ``GLContext``) whose failure leaves nothing behind that fails again: GLFW's
    raises in ``__init__`` before it has a ``_context`` (no X display), and its ``__del__`` then raised
    AttributeError whenever the half-made object was collected (an "unraisable" error in whatever ran then)."""
    context = kind.__new__(kind)
    context._context = None  # noqa: SLF001 - what its free() (run by __del__) reads, set before __init__ can fail
    kind.__init__(context, width, height)
    return context


def warm_up_gl() -> None:
    """Have the current OpenGL context's driver compile what MuJoCo's context needs first (mipmap generation of a
    texture), through PyOpenGL's calls, which release the interpreter lock. Only the time moves: nothing is left
    drawn or bound. Best effort: without PyOpenGL, or if the driver refuses, MuJoCo's context pays as before."""
    try:
        from OpenGL import GL
        from OpenGL import error as gl_error
    except ImportError:
        return
    try:
        texture = GL.glGenTextures(1)
    except gl_error.Error:
        return
    try:
        GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
        pixels = np.zeros((WARM_TEXTURE_PX, WARM_TEXTURE_PX, 3), dtype=np.uint8)
        GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_RGB, WARM_TEXTURE_PX, WARM_TEXTURE_PX, 0, GL.GL_RGB,
                        GL.GL_UNSIGNED_BYTE, pixels)
        GL.glGenerateMipmap(GL.GL_TEXTURE_2D)
        GL.glFinish()
    except gl_error.Error:
        pass
    finally:
        try:
            GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
            GL.glDeleteTextures([texture])
        except gl_error.Error:
            pass


class OffscreenRenderer:
    """``mujoco.Renderer`` for RGB pictures (its ``update_scene``, ``scene``, ``render``, ``close``), made in steps:
    its OpenGL context, :func:`warm_up_gl` there, then MuJoCo's scene and context. The drawing is MuJoCo's own
    (``mjv_updateScene``, ``mjr_render``, ``mjr_readPixels``), so a picture is the same as ``mujoco.Renderer``'s."""

    def __init__(self, model: mujoco.MjModel, height: int, width: int, max_geoms: int = MAX_GEOMS) -> None:
        if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
            raise ValueError(f"{width}x{height} is larger than the model's offscreen buffer "
                             f"({model.vis.global_.offwidth}x{model.vis.global_.offheight})")
        from mujoco import gl_context

        self._model = model
        self._width, self._height = width, height
        self._gl: Any = None
        self._mjr: mujoco.MjrContext | None = None
        if gl_context.GLContext is None:
            raise RuntimeError("MuJoCo has no OpenGL back end here (MUJOCO_GL)")
        self._gl = _new_gl_context(gl_context.GLContext, width, height)
        try:
            self._gl.make_current()
            warm_up_gl()
            self._scene = mujoco.MjvScene(model=model, maxgeom=max_geoms)
            self._option = mujoco.MjvOption()
            self._rect = mujoco.MjrRect(0, 0, width, height)
            self._mjr = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._mjr)
        except BaseException:
            self.close()
            raise

    @property
    def scene(self) -> mujoco.MjvScene:
        return self._scene

    def update_scene(self, data: mujoco.MjData, camera: mujoco.MjvCamera) -> None:
        mujoco.mjv_updateScene(self._model, data, self._option, None, camera, mujoco.mjtCatBit.mjCAT_ALL.value,
                               self._scene)

    def render(self) -> np.ndarray:
        """(height, width, 3) uint8 RGB, top row first."""
        if self._mjr is None:
            raise RuntimeError("render cannot be called after close")
        self._gl.make_current()
        pixels = np.empty((self._height, self._width, 3), dtype=np.uint8)
        mujoco.mjr_render(self._rect, self._scene, self._mjr)
        mujoco.mjr_readPixels(pixels, None, self._rect, self._mjr)
        return np.flipud(pixels).copy()  # OpenGL's first row is the bottom one

    def close(self) -> None:
        if self._mjr is not None and self._gl is not None:
            self._gl.make_current()
            self._mjr.free()
        self._mjr = None
        if self._gl is not None:
            self._gl.free()
        self._gl = None


class SceneRenderer:
    """Renders ``world`` at ``width`` × ``height`` pixels from a camera that follows the body's centroid."""

    def __init__(self, world: PhysicsWorld, width: int = 640, height: int = 480) -> None:
        self.world = world
        try:
            self._renderer = OffscreenRenderer(world.model, height=height, width=width)
        except Exception as exc:  # noqa: BLE001 - GL back ends fail with many types; all mean "cannot render here"
            raise RenderUnavailable(f"no OpenGL rendering for the 3-D view ({type(exc).__name__}: {exc})") from exc
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._camera.distance = CAMERA_DISTANCE_M
        self._camera.azimuth = CAMERA_AZIMUTH_DEG
        self._camera.elevation = CAMERA_ELEVATION_DEG
        self.frames = 0

    def render(self, marks: Sequence[Mark] = ()) -> np.ndarray:
        """One frame, (height, width, 3) uint8 RGB, with ``marks`` drawn into the scene (spheres at given points:
        the motion-captured markers, drawn over the simulated body)."""
        self.world.update_scene(self._renderer, self._camera)
        add_marks(self._renderer.scene, marks)
        frame = self._renderer.render()
        self.frames += 1
        return frame

    def close(self) -> None:
        self._renderer.close()


class ThreadRenderers:
    """One :class:`SceneRenderer` of ``world`` per calling thread (an OpenGL context is current in the thread that
    made it), made on a thread's first :meth:`render` and again when the size changes."""

    def __init__(self, world: PhysicsWorld) -> None:
        self.world = world
        self._renderers: dict[int, tuple[tuple[int, int], SceneRenderer]] = {}

    def render(self, width: int, height: int, marks: Sequence[Mark] = ()) -> np.ndarray:
        thread = threading.get_ident()
        entry = self._renderers.get(thread)
        if entry is None or entry[0] != (width, height):
            if entry is not None:
                entry[1].close()
            entry = ((width, height), SceneRenderer(self.world, width, height))
            self._renderers[thread] = entry
        return entry[1].render(marks)

    def release(self) -> None:
        """Close the calling thread's renderer, if it has one (only that thread can: EGL_BAD_ACCESS otherwise)."""
        entry = self._renderers.pop(threading.get_ident(), None)
        if entry is not None:
            entry[1].close()
