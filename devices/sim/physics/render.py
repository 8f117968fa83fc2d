"""Pictures of the physics lab: an offscreen MuJoCo renderer (EGL on Linux) following the robot.

Thread: a renderer owns an OpenGL context made current in the thread that created it; call :meth:`render` from that
thread only (the app's GUI thread). The world is read under its lock (``PhysicsWorld.update_scene``), drawing happens
outside it, so the physics thread is held up only for the scene update.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import NamedTuple

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


class SceneRenderer:
    """Renders ``world`` at ``width`` × ``height`` pixels from a camera that follows the body's centroid."""

    def __init__(self, world: PhysicsWorld, width: int = 640, height: int = 480) -> None:
        self.world = world
        try:
            self._renderer = mujoco.Renderer(world.model, height=height, width=width)
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
